//! `edgenerf edges`: compute the edge masks of a scene's views and write them with an
//! overlay to look at; and [`EdgeArgs`], the edge options shared with `train`.

use std::path::{Path, PathBuf};

use edgenerf::data::ImageRgb;
use edgenerf::edges::{EdgeConfig, EdgeMask, EdgeSource, Polarity, edge_masks, mask_stem};

/// The edge options (flatten into a command with `#[command(flatten)]`). Each flag left
/// out keeps the config's value.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct EdgeArgs {
    /// Edge source: `canny` (detect on the images), `none` (no edges: global smoothing),
    /// or a directory of precomputed edge maps (e.g. DexiNed), one PNG/JPEG per image
    /// named after it (write `./canny` for a directory called canny).
    #[arg(long = "edges", value_name = "canny|none|DIR")]
    pub edges: Option<String>,
    /// Polarity of external maps: `dark` edges on white (DexiNed) or `bright` on black.
    #[arg(long, value_enum, value_name = "dark|bright")]
    pub edge_polarity: Option<PolarityArg>,
    /// Binarization threshold on an external map's grey level 0..255 (default 125).
    /// Canny's map is 0 or 255, so with `--edges canny` any value in 1..255 gives the
    /// same mask (0 makes every pixel an edge).
    #[arg(long, allow_negative_numbers = true, value_name = "LEVEL")]
    pub tau_e: Option<f32>,
    /// Do not widen edge regions with the 3x3 dilation.
    #[arg(long)]
    pub no_dilate: bool,
    /// Canny: Gaussian blur sigma in pixels (default 2).
    #[arg(long, allow_negative_numbers = true, value_name = "PIXELS")]
    pub canny_sigma: Option<f32>,
    /// Canny: low threshold, a fraction of the image's largest gradient (default 0.05).
    #[arg(long, allow_negative_numbers = true, value_name = "FRACTION")]
    pub canny_low: Option<f32>,
    /// Canny: high threshold, a fraction of the image's largest gradient (default 0.15).
    #[arg(long, allow_negative_numbers = true, value_name = "FRACTION")]
    pub canny_high: Option<f32>,
}

/// `--edge-polarity` values.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum PolarityArg {
    Dark,
    Bright,
}

impl EdgeArgs {
    /// Writes the options that were given into `cfg` (the rest stays as it is).
    pub fn apply(&self, cfg: &mut EdgeConfig) {
        match self.edges.as_deref() {
            None => {}
            Some("canny") => cfg.source = EdgeSource::Canny,
            Some("none") => cfg.source = EdgeSource::None,
            Some(dir) => {
                cfg.source = EdgeSource::External;
                cfg.dir = Some(PathBuf::from(dir));
            }
        }
        if let Some(p) = self.edge_polarity {
            cfg.polarity = match p {
                PolarityArg::Dark => Polarity::DarkEdges,
                PolarityArg::Bright => Polarity::BrightEdges,
            };
        }
        if let Some(t) = self.tau_e {
            cfg.tau_e = t;
        }
        if self.no_dilate {
            cfg.dilate = false;
        }
        if let Some(s) = self.canny_sigma {
            cfg.canny.sigma = s;
        }
        if let Some(l) = self.canny_low {
            cfg.canny.low = l;
        }
        if let Some(h) = self.canny_high {
            cfg.canny.high = h;
        }
    }
}

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    input: super::SceneArgs,
    /// Output directory: per view `<name>.png` (the mask: white = non-edge, black =
    /// edge) and `<name>_overlay.png` (the image dimmed, edges in yellow).
    #[arg(long)]
    out: PathBuf,
    /// Every view of the scene, not only the training views.
    #[arg(long)]
    all: bool,
    #[command(flatten)]
    edge: EdgeArgs,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let mut cfg = EdgeConfig::default();
    args.edge.apply(&mut cfg);
    // Before any work: masks written into the scene (`--out SCENE/train`) replaced its
    // training images; a file as --out gave a raw OS error after the masks were made.
    let mut inputs = vec![(args.input.scene.as_path(), "the scene directory")];
    if let (EdgeSource::External, Some(dir)) = (cfg.source, cfg.dir.as_deref()) {
        inputs.push((dir, "the edge maps' directory"));
    }
    crate::output::refuse_inside_inputs(&args.out, "--out", &inputs)?;
    if args.out.exists() && !args.out.is_dir() {
        anyhow::bail!("--out {} is a file; pass a directory (it is created when missing)", args.out.display());
    }
    let scene = args.input.load()?;
    let views: Vec<usize> = if args.all { (0..scene.views.len()).collect() } else { scene.split.train.clone() };
    let masks = edge_masks(&scene, &views, &cfg)?;
    crate::output::ensure_dir(&args.out, "--out")?;
    println!("edges: {}", describe(&cfg));
    let mut total = 0.0;
    for (&v, mask) in views.iter().zip(&masks) {
        let stem = mask_stem(&scene, v);
        mask.save_png(&args.out.join(format!("{stem}.png")))?;
        overlay(&scene.views[v].image, mask).save_png(args.out.join(format!("{stem}_overlay.png")))?;
        let f = mask.edge_fraction();
        total += f;
        println!("view {v:>3} ({stem}): edge fraction {:.3} ({:.1}% of pixels)", f, 100.0 * f);
    }
    if !views.is_empty() {
        let mean = total / views.len() as f32;
        println!("mean edge fraction {mean:.3} over {} views", views.len());
    }
    eprintln!("wrote masks and overlays to {}", args.out.display());
    Ok(())
}

/// One line saying where edges come from and with which settings.
fn describe(cfg: &EdgeConfig) -> String {
    let dilate = if cfg.dilate { ", edges dilated 3x3" } else { "" };
    match cfg.source {
        EdgeSource::None => "none (every pixel non-edge)".to_string(),
        EdgeSource::Canny => {
            let c = &cfg.canny;
            format!("canny on luma, sigma {} px, thresholds {} / {} of the largest gradient{dilate}", c.sigma, c.low, c.high)
        }
        EdgeSource::External => {
            let dir = cfg.dir.as_deref().unwrap_or(Path::new("?"));
            let p = match cfg.polarity {
                Polarity::DarkEdges => "dark edges, non-edge where",
                Polarity::BrightEdges => "bright edges, edge where",
            };
            format!("external maps in {} ({p} grey >= {}){dilate}", dir.display(), cfg.tau_e)
        }
    }
}

/// The image at 40% brightness with edge pixels in yellow.
fn overlay(image: &ImageRgb, mask: &EdgeMask) -> ImageRgb {
    let mut out = ImageRgb::new(mask.width, mask.height);
    for y in 0..mask.height {
        for x in 0..mask.width {
            let rgb = if mask.is_edge(x, y) {
                [1.0, 0.9, 0.0]
            } else if image.is_empty() {
                [0.0; 3]
            } else {
                image.get(x, y).map(|c| 0.4 * c)
            };
            out.set(x, y, rgb);
        }
    }
    out
}
