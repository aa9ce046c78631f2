//! The renderer against exact answers and against an independent renderer's reference.
//!
//! Every tolerance is a number of combined standard errors: ours from the film's per-pixel
//! variance, the reference's from its standard-error image.

mod common;

use std::path::{Path, PathBuf};

use arbor::bvh::builders::Builder;
use arbor::image_io::{Image, read_exr};
use arbor::render::RenderScene;
use arbor::render::film::Film;
use arbor::scene::Scene;
use glam::Vec3;

fn render(scene: &Scene, spp: u32, max_depth: u32) -> Film {
    let (rs, _) = RenderScene::build(scene, &"lbvh".parse::<Builder>().unwrap());
    let mut film = Film::new(rs.width, rs.height);
    rs.render(&mut film, scene.render.seed, max_depth, 0..spp, &|_| {});
    assert_eq!(film.non_finite_count(), 0, "non-finite samples");
    film
}

/// Mean and standard error of the mean over the pixels `mask` selects, per channel.
fn region(mean: &Image, stderr: &Image, mask: impl Fn(u32, u32) -> bool) -> (Vec3, Vec3, usize) {
    let (mut sum, mut var, mut n) = (Vec3::ZERO.as_dvec3(), Vec3::ZERO.as_dvec3(), 0usize);
    for y in 0..mean.height {
        for x in 0..mean.width {
            if mask(x, y) {
                let i = (y * mean.width + x) as usize;
                sum += Vec3::from(mean.pixels[i]).as_dvec3();
                var += (Vec3::from(stderr.pixels[i]) * Vec3::from(stderr.pixels[i])).as_dvec3();
                n += 1;
            }
        }
    }
    let n_f = n as f64;
    ((sum / n_f).as_vec3(), (var.powf(0.5) / n_f).as_vec3(), n)
}

/// Which pixels a region covers.
type Mask = Box<dyn Fn(u32, u32) -> bool>;

fn reference_dir() -> Option<PathBuf> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/reference/cornell-box");
    if dir.exists() {
        return Some(dir);
    }
    assert!(std::env::var("CI").map_or(true, |v| v != "true"), "CI must have {}", dir.display());
    eprintln!("skipping: {} not found", dir.display());
    None
}

fn read_pgm(path: &Path) -> (u32, u32, Vec<u8>) {
    let bytes = std::fs::read(path).unwrap();
    let mut fields = Vec::new();
    let mut pos = 0;
    while fields.len() < 4 {
        while bytes[pos].is_ascii_whitespace() {
            pos += 1;
        }
        let start = pos;
        while !bytes[pos].is_ascii_whitespace() {
            pos += 1;
        }
        fields.push(String::from_utf8_lossy(&bytes[start..pos]).into_owned());
    }
    assert_eq!(fields[0], "P5");
    let (w, h): (u32, u32) = (fields[1].parse().unwrap(), fields[2].parse().unwrap());
    (w, h, bytes[pos + 1..].to_vec())
}

/// Per surface (the reference's label mask) and per block of a 4x4 grid: |ours - reference|
/// within 3 combined standard errors.
#[test]
fn cornell_box_matches_the_reference() {
    let Some(dir) = reference_dir() else { return };
    let scene = Scene::load(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell-box.toml")).unwrap();
    let film = render(&scene, 128, 8);
    let (ours, ours_se) = (film.mean(), film.stderr());
    let reference = read_exr(dir.join("cornell_spp4096.exr")).unwrap();
    let reference_se = read_exr(dir.join("cornell_spp4096_stderr.exr")).unwrap();
    let (w, h, labels) = read_pgm(&dir.join("cornell_labels.pgm"));
    assert_eq!((w, h), (ours.width, ours.height));
    let mut regions: Vec<(String, Mask)> = Vec::new();
    for label in 0..=17u8 {
        let labels = labels.clone();
        regions.push((format!("surface {label}"), Box::new(move |x, y| labels[(y * w + x) as usize] == label)));
    }
    for by in 0..4 {
        for bx in 0..4 {
            regions.push((format!("block ({bx}, {by})"), Box::new(move |x, y| x / 64 == bx && y / 64 == by)));
        }
    }
    let mut report = Vec::new();
    let mut worst = 0.0f32;
    for (name, mask) in &regions {
        let (m1, s1, n) = region(&ours, &ours_se, mask);
        if n == 0 {
            continue;
        }
        let (m2, s2, _) = region(&reference, &reference_se, mask);
        let z = (m1 - m2).abs() / (s1 * s1 + s2 * s2).powf(0.5);
        worst = worst.max(z.max_element());
        report.push(format!("{name:>16} ({n:>5} px): ours {m1:.5} ref {m2:.5} z {z:.2}"));
    }
    eprintln!("{}\nworst z = {worst:.2}", report.join("\n"));
    assert!(worst <= 3.0, "a region differs from the reference by more than 3 standard errors:\n{}", report.join("\n"));
}
