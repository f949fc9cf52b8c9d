//! PNG figures of the benchmark report: training PSNR against wall time (one panel
//! per scene, one line per configuration), grouped bars of geometry metrics per
//! scene, and image strips (ground truth, then each configuration; rows RGB, depth,
//! normals).
//!
//! Drawn with plotters into an RGB buffer that the `image` crate encodes; text goes
//! through plotters' ab_glyph backend with the committed Roboto font
//! (`tools/assets/fonts/`), so no system font is needed. Each configuration keeps one
//! colour across all figures ([`colour`]).

use std::path::{Path, PathBuf};
use std::sync::Once;

use anyhow::{Context, anyhow, bail};
use edgenerf::data::{ImageRgb, LoadOptions, Scene};
use edgenerf::edges::mask_stem;
use edgenerf::metrics::valid_depth;
use plotters::prelude::*;
use plotters::style::FontStyle;

const FONT: &str = "sans-serif";

/// Registers the embedded font with plotters (once per process).
fn ensure_font() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // The font is a valid TTF checked in with the sources; failing here is a build error in effect.
        plotters::style::register_font(FONT, FontStyle::Normal, include_bytes!("../assets/fonts/Roboto-Regular.ttf"))
            .unwrap_or_else(|_| panic!("the embedded Roboto font does not parse"));
    });
}

/// Tableau-10 colours, one per configuration index (cycling).
pub fn colour(i: usize) -> RGBColor {
    const C: [(u8, u8, u8); 10] = [
        (31, 119, 180),
        (255, 127, 14),
        (44, 160, 44),
        (214, 39, 40),
        (148, 103, 189),
        (140, 86, 75),
        (227, 119, 194),
        (127, 127, 127),
        (188, 189, 34),
        (23, 190, 207),
    ];
    let (r, g, b) = C[i % C.len()];
    RGBColor(r, g, b)
}

/// Encodes an RGB buffer as PNG.
fn save(buf: Vec<u8>, w: u32, h: u32, path: &Path) -> anyhow::Result<()> {
    let img = image::RgbImage::from_raw(w, h, buf).ok_or_else(|| anyhow!("plot buffer of the wrong size"))?;
    img.save_with_format(path, image::ImageFormat::Png).with_context(|| format!("writing {}", path.display()))
}

fn plot_err<E: std::fmt::Debug>(e: E) -> anyhow::Error {
    anyhow!("drawing a plot: {e:?}")
}

/// A legend across the top of `area`: a colour swatch and the name of each config
/// where `shown(i)` (configs without data are left out; colours stay by index).
fn legend<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    configs: &[String],
    shown: impl Fn(usize) -> bool,
) -> anyhow::Result<()> {
    let style = (FONT, 16).into_font().color(&BLACK);
    let mut x = 12i32;
    for (i, c) in configs.iter().enumerate().filter(|(i, _)| shown(*i)) {
        area.draw(&Rectangle::new([(x, 9), (x + 14, 23)], colour(i).filled())).map_err(plot_err)?;
        area.draw_text(c, &style, (x + 20, 7)).map_err(plot_err)?;
        let (tw, _) = area.estimate_text_size(c, &style).map_err(plot_err)?;
        x += 20 + tw as i32 + 24;
    }
    Ok(())
}

/// The training curves of one scene: `(config, [(seconds, PSNR)])`.
pub struct Curves {
    pub title: String,
    pub lines: Vec<(String, Vec<(f64, f64)>)>,
}

/// `psnr_vs_time.png`: one panel per scene, a line per configuration.
pub fn psnr_vs_time(panels: &[Curves], configs: &[String], path: &Path) -> anyhow::Result<()> {
    ensure_font();
    let cols = panels.len().clamp(1, 3);
    let rows = panels.len().div_ceil(cols).max(1);
    let (pw, ph, top) = (440u32, 300u32, 32u32);
    let (w, h) = (pw * cols as u32, ph * rows as u32 + top);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(plot_err)?;
        let (head, body) = root.split_vertically(top);
        legend(&head, configs, |i| panels.iter().any(|p| p.lines.iter().any(|l| l.0 == configs[i])))?;
        for (panel, area) in panels.iter().zip(body.split_evenly((rows, cols))) {
            let t_max = panel.lines.iter().flat_map(|l| l.1.iter().map(|p| p.0)).fold(1e-3f64, f64::max);
            let ps: Vec<f64> = panel.lines.iter().flat_map(|l| l.1.iter().map(|p| p.1)).filter(|p| p.is_finite()).collect();
            let lo = ps.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = ps.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            let (lo, hi) = if lo.is_finite() { ((lo - 1.0).floor(), (hi + 1.0).ceil()) } else { (0.0, 40.0) };
            let mut chart = ChartBuilder::on(&area)
                .caption(&panel.title, (FONT, 18))
                .margin(8)
                .x_label_area_size(36)
                .y_label_area_size(44)
                .build_cartesian_2d(0f64..t_max * 1.02, lo..hi)
                .map_err(plot_err)?;
            chart
                .configure_mesh()
                .x_desc("wall time (s)")
                .y_desc("train PSNR (dB)")
                .label_style((FONT, 13))
                .axis_desc_style((FONT, 14))
                .light_line_style(RGBColor(235, 235, 235))
                .draw()
                .map_err(plot_err)?;
            for (name, pts) in &panel.lines {
                let i = configs.iter().position(|c| c == name).unwrap_or(0);
                chart.draw_series(LineSeries::new(pts.iter().copied(), colour(i).stroke_width(2))).map_err(plot_err)?;
            }
        }
        root.present().map_err(plot_err)?;
    }
    save(buf, w, h, path)
}

/// One panel of [`grouped_bars`]: `values[scene][config]`.
pub struct BarPanel {
    pub title: String,
    pub values: Vec<Vec<Option<f64>>>,
}

/// `geometry.png`: per panel, a group of bars per scene, one bar per configuration.
pub fn grouped_bars(panels: &[BarPanel], scenes: &[String], configs: &[String], path: &Path) -> anyhow::Result<()> {
    ensure_font();
    let n = scenes.len().max(1);
    let (pw, ph, top) = ((120 * n as u32 + 100).max(560), 280u32, 32u32);
    let (w, h) = (pw, ph * panels.len() as u32 + top);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(plot_err)?;
        let (head, body) = root.split_vertically(top);
        legend(&head, configs, |i| panels.iter().any(|p| p.values.iter().any(|row| row.get(i).is_some_and(Option::is_some))))?;
        for (panel, area) in panels.iter().zip(body.split_evenly((panels.len(), 1))) {
            let max = panel.values.iter().flatten().flatten().copied().filter(|v| v.is_finite()).fold(0.0f64, f64::max);
            let mut chart = ChartBuilder::on(&area)
                .caption(&panel.title, (FONT, 18))
                .margin(8)
                .x_label_area_size(28)
                .y_label_area_size(52)
                .build_cartesian_2d(-0.5f64..n as f64 - 0.5, 0f64..(max * 1.1).max(1e-6))
                .map_err(plot_err)?;
            chart
                .configure_mesh()
                .disable_x_mesh()
                .x_label_formatter(&|_| String::new())
                .label_style((FONT, 13))
                .light_line_style(RGBColor(235, 235, 235))
                .draw()
                .map_err(plot_err)?;
            // Scene names under their groups (plotters' own labels sit at round numbers).
            let style = (FONT, 14).into_font().color(&BLACK);
            for (s, name) in scenes.iter().enumerate() {
                let (px, py) = chart.backend_coord(&(s as f64, 0.0));
                let (tw, _) = root.estimate_text_size(name, &style).map_err(plot_err)?;
                root.draw_text(name, &style, (px - tw as i32 / 2, py + 8)).map_err(plot_err)?;
            }
            let k = configs.len().max(1) as f64;
            let bw = 0.8 / k;
            for (s, row) in panel.values.iter().enumerate() {
                for (c, v) in row.iter().enumerate() {
                    let Some(v) = v.filter(|v| v.is_finite()) else { continue };
                    let x0 = s as f64 - 0.4 + c as f64 * bw;
                    chart.draw_series(std::iter::once(Rectangle::new([(x0, 0.0), (x0 + bw * 0.9, v)], colour(c).filled()))).map_err(plot_err)?;
                }
            }
        }
        root.present().map_err(plot_err)?;
    }
    save(buf, w, h, path)
}

fn to_rgb8(img: &ImageRgb) -> image::RgbImage {
    let bytes = img.data.iter().map(|&v| (v.clamp(0.0, 1.0) * 255.0).round() as u8).collect();
    image::RgbImage::from_raw(img.width, img.height, bytes).expect("ImageRgb holds 3 values per pixel")
}

/// `strip_<scene>.png`: columns ground truth, then each `(config, eval dir, view stem)`
/// (the renders `eval` wrote), rows RGB, depth, normals. Ground-truth depth and
/// normals are drawn where the scene has them (grey cells otherwise).
pub fn image_strip(scene_path: &Path, columns: &[(String, PathBuf, String)], path: &Path) -> anyhow::Result<()> {
    ensure_font();
    let Some((_, _, stem)) = columns.first() else { bail!("no finished run to show") };
    let scene = Scene::load(scene_path, &LoadOptions::default()).with_context(|| format!("loading {}", scene_path.display()))?;
    let v = (0..scene.views.len()).find(|&v| &mask_stem(&scene, v) == stem).ok_or_else(|| anyhow!("view {stem} not in the scene"))?;
    let view = &scene.views[v];
    let (iw, ih) = (view.image.width, view.image.height);
    let gt_depth = view.depth.as_deref().filter(|_| scene.ndc.is_none()).map(|d| {
        let valid: Vec<bool> = d.iter().map(|&g| valid_depth(g)).collect();
        to_rgb8(&edgenerf::viz::depth_image(iw, ih, d, Some(&valid)).0)
    });
    let gt_normal = view.normal.as_deref().map(|n| to_rgb8(&edgenerf::viz::normal_image(iw, ih, n)));
    let mut cells: Vec<(String, [Option<image::RgbImage>; 3])> = vec![("ground truth".into(), [Some(to_rgb8(&view.image)), gt_depth, gt_normal])];
    for (name, dir, stem) in columns {
        let load = |what: &str| image::open(dir.join(format!("{stem}_{what}.png"))).ok().map(|i| i.to_rgb8());
        cells.push((name.clone(), [load("rgb"), load("depth"), load("normal")]));
    }
    // Cells about 256 px high: small images doubled (nearest), large ones shrunk.
    let scale = 256.0 / ih as f64;
    let scale = if scale >= 2.0 { scale.floor() } else { scale.min(1.0) };
    let (cw, ch) = (((iw as f64 * scale).round() as u32).max(1), ((ih as f64 * scale).round() as u32).max(1));
    let (left, top, gap) = (80u32, 30u32, 4u32);
    let w = left + cells.len() as u32 * (cw + gap);
    let h = top + 3 * (ch + gap);
    let mut canvas = image::RgbImage::from_pixel(w, h, image::Rgb([255, 255, 255]));
    for (c, (_, imgs)) in cells.iter().enumerate() {
        for (r, img) in imgs.iter().enumerate() {
            let (x, y) = (left + c as u32 * (cw + gap), top + r as u32 * (ch + gap));
            let tile = match img {
                Some(img) => {
                    let filter = if scale >= 1.0 { image::imageops::FilterType::Nearest } else { image::imageops::FilterType::Triangle };
                    image::imageops::resize(img, cw, ch, filter)
                }
                None => image::RgbImage::from_pixel(cw, ch, image::Rgb([200, 200, 200])),
            };
            image::imageops::replace(&mut canvas, &tile, x as i64, y as i64);
        }
    }
    let mut buf = canvas.into_raw();
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        let style = (FONT, 16).into_font().color(&BLACK);
        for (c, (name, _)) in cells.iter().enumerate() {
            root.draw_text(name, &style, ((left + c as u32 * (cw + gap) + 4) as i32, 7)).map_err(plot_err)?;
        }
        for (r, name) in ["RGB", "depth", "normals"].iter().enumerate() {
            root.draw_text(name, &style, (8, (top + r as u32 * (ch + gap) + ch / 2 - 8) as i32)).map_err(plot_err)?;
        }
        root.present().map_err(plot_err)?;
    }
    save(buf, w, h, path)
}
