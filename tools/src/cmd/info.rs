//! `edgenerf info`: describe a scene directory and the Vulkan adapter in use.

use anyhow::Context;
use edgenerf::data::Lens;
use edgenerf::gpu::{Gpu, GpuOptions};

use super::SceneArgs;

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    input: SceneArgs,
    /// Do not open the GPU (describe the scene only).
    #[arg(long)]
    no_gpu: bool,
    /// Also run the GPU self-test (a float-atomic scatter-add checked against the CPU).
    #[arg(long)]
    check_gpu: bool,
}

fn ids(list: &[usize]) -> String {
    format!("{list:?}")
}

pub fn run(args: Args, gpu_opts: &GpuOptions) -> anyhow::Result<()> {
    // Images are loaded (not only headers) so that masks and ground truth are reported
    // as they will be seen by training.
    let scene = args.input.load()?;
    let (w, h) = scene.image_size();
    println!("scene       {}", scene.root.display());
    println!("format      {}", scene.format);
    println!("images      {} of {w}x{h}", scene.views.len());
    let k = args.input.views.map_or("all".to_string(), |k| k.to_string());
    println!("train ids   {} ({k} views)", ids(&scene.split.train));
    println!("test ids    {} ({} views)", ids(&scene.split.test), scene.split.test.len());
    let space = if scene.ndc.is_some() { " (NDC)" } else { "" };
    println!("near/far    {} / {}{space}", scene.near, scene.far);
    println!("aabb        {:?} .. {:?}", scene.aabb[0].to_array(), scene.aabb[1].to_array());
    if let Some(v) = scene.views.first() {
        let c = &v.camera;
        println!("intrinsics  fx {:.2} fy {:.2} cx {:.2} cy {:.2} (view 0)", c.fx, c.fy, c.cx, c.cy);
        match c.lens {
            Lens::Pinhole => {}
            Lens::OpenCv { k, p } => println!("lens        OPENCV k1..k4 {k:?} p1 p2 {p:?} (view 0; distorted rays)"),
            Lens::Fisheye { k } => println!("lens        OPENCV_FISHEYE k1..k4 {k:?} (view 0; distorted rays)"),
        }
    }
    let has = |f: &dyn Fn(&edgenerf::data::View) -> bool| scene.views.iter().all(f);
    println!(
        "ground truth  masks: {}  depth: {}  normals: {}",
        yes_no(has(&|v| v.mask.is_some())),
        yes_no(has(&|v| v.depth.is_some())),
        yes_no(has(&|v| v.normal.is_some()))
    );
    if !args.no_gpu {
        let gpu = Gpu::new(gpu_opts).context("opening the GPU (use --no-gpu to skip)")?;
        println!("adapter     {}", gpu.adapter());
        if args.check_gpu {
            edgenerf::gpu::selftest::check(&gpu).map_err(|e| anyhow::anyhow!("GPU self-test failed: {e}"))?;
            println!("gpu check   ok (float-atomic scatter-add matches the CPU)");
        }
    }
    Ok(())
}

fn yes_no(b: bool) -> &'static str {
    if b { "yes" } else { "no" }
}
