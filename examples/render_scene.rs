//! Renders a scene file to an image through [`arbor::device::Renderer`], the entry point the
//! `render` binary uses.
//!
//! `cargo run --release --example render_scene -- scenes/cornell-box.toml cornell.png [gpu]`

use arbor::device::{BuilderChoice, DeviceChoice, Renderer};
use arbor::render::first_frame_time;
use arbor::scene::{RenderSettings, Scene};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [scene_path, output, rest @ ..] = args.as_slice() else {
        return Err("usage: render_scene SCENE.toml OUT.png|OUT.exr [gpu]".into());
    };
    let device = if rest.first().is_some_and(|d| d == "gpu") { DeviceChoice::Gpu } else { DeviceChoice::Cpu };
    let scene = Scene::load(scene_path)?;
    // The scene's [render] table, at 16 samples per pixel.
    let settings = RenderSettings { spp: 16, ..scene.render };
    let (device, _) = device.select()?;
    // The form the CPU traces: the best this CPU has, or the path `ARBOR_SIMD` names.
    let tracing = arbor::bvh::Tracing::from_env(None)?;
    let mut renderer =
        Renderer::new(device, &scene, &BuilderChoice::Auto, tracing, &settings, 1, first_frame_time(&scene))?;
    println!("BVH: {}", renderer.build_report().builder);
    let frame = renderer.render(&settings, &|_| {})?;
    // Written to a temporary file and renamed: never a half-written image.
    arbor::image_io::write_image(output, &frame.film.mean())?;
    println!("{output}: {} spp in {:.2} s on the {}", frame.samples, frame.seconds, device.name());
    Ok(())
}
