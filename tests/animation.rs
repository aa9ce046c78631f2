//! Animated scenes: a frame rendered through the kept-alive two-level BVH equals, within Monte
//! Carlo noise, the static scene with every object placed at that frame's transform.

use arbor::bvh::build::Builder;
use arbor::bvh::dynamic::instances::TopLevelUpdate;
use arbor::render::RenderScene;
use arbor::render::film::Film;
use arbor::render::geometry::Geometry;
use arbor::scene::Scene;

/// A diffuse Cornell-like box lit from the ceiling, with a sphere moving by keyframes and a cube
/// orbiting: diffuse only, so the noise is well behaved for a z-test.
const SCENE: &str = r#"
[camera]
position = [0, 0, 3.9]
look_at = [0, 0, 0]
fov = 39.3
resolution = [32, 32]

[animation]
fps = 10
frames = [0, 40]

[materials.white]
type = "diffuse"
albedo = [0.8, 0.8, 0.8]
[materials.red]
type = "diffuse"
albedo = [0.8, 0.1, 0.1]
[materials.light]
type = "emissive"
radiance = [10, 10, 10]

[[objects]]
shape = "quad"
material = "light"
translate = [0, 0.99, 0]
rotate = [90, 0, 0]
scale = 0.3
[[objects]]
shape = "quad"
material = "white"
translate = [0, -1, 0]
rotate = [-90, 0, 0]
[[objects]]
shape = "quad"
material = "white"
translate = [0, 1, 0]
rotate = [90, 0, 0]
[[objects]]
shape = "quad"
material = "white"
translate = [0, 0, -1]
[[objects]]
shape = "quad"
material = "red"
translate = [-1, 0, 0]
rotate = [0, 90, 0]
[[objects]]
shape = "quad"
material = "white"
translate = [1, 0, 0]
rotate = [0, -90, 0]
[[objects]]
shape = "sphere"
material = "red"
scale = 0.3
[[objects.keyframes]]
time = 0.0
translate = [-0.5, -0.6, 0]
[[objects.keyframes]]
time = 4.0
translate = [0.5, 0.3, -0.2]
[[objects]]
shape = "box"
material = "white"
scale = 0.15
[objects.scatter]
count = 1
min = [0.2, -0.5, 0.3]
max = [0.2, -0.5, 0.3]
radius = 0.4
period = 3.0
"#;

fn render(rs: &RenderScene, seed: u64, spp: u32) -> Film {
    let mut film = Film::new(rs.width, rs.height);
    rs.render(&mut film, seed, 5, 0..spp, &|_| {});
    film
}

/// The largest |z| over 4x4-pixel blocks and channels between two independent renders.
fn max_block_z(a: &Film, b: &Film) -> f64 {
    let (w, h) = (a.width(), a.height());
    let mut worst = 0.0f64;
    for by in (0..h).step_by(4) {
        for bx in (0..w).step_by(4) {
            for c in 0..3 {
                let (mut d, mut var) = (0.0f64, 0.0f64);
                for y in by..by + 4 {
                    for x in bx..bx + 4 {
                        let (pa, pb) = (a.pixel(x, y).unwrap(), b.pixel(x, y).unwrap());
                        d += pa.mean()[c] as f64 - pb.mean()[c] as f64;
                        var += (pa.stderr()[c] as f64).powi(2) + (pb.stderr()[c] as f64).powi(2);
                    }
                }
                if var > 0.0 {
                    worst = worst.max(d.abs() / var.sqrt());
                }
            }
        }
    }
    worst
}

#[test]
fn animated_frame_equals_the_static_scene_at_that_time() {
    let scene = Scene::parse(SCENE, "animated.toml").unwrap();
    assert!(scene.is_animated());
    let builder: Builder = "lbvh+prbvh".parse().unwrap();
    let (mut animated, _) = RenderScene::build(&scene, &builder, crate::common::tracing());
    assert!(matches!(animated.geometry, Geometry::Instanced(_)));
    // Walk the animation frame by frame to 30, as a sequence render does, keeping the tree.
    let update = TopLevelUpdate::Dynamic(Default::default());
    for f in 1..=30 {
        animated.set_time(&scene, scene.frame_time(f), &update).unwrap();
        let Geometry::Instanced(g) = &animated.geometry else { unreachable!() };
        g.two_level.top_level().validate(g.two_level.instance_boxes()).unwrap();
    }
    let t = scene.frame_time(30);
    let (fixed, _) = RenderScene::build(&scene.at_time(t), &builder, crate::common::tracing());
    assert!(matches!(fixed.geometry, Geometry::Flat(_)), "a static scene takes the flat path");
    let spp = 256;
    let a = render(&animated, 1, spp);
    let b = render(&fixed, 2, spp);
    assert_eq!(a.non_finite_count() + b.non_finite_count(), 0);
    // 64 blocks x 3 channels; |z| <= 4.3 is a two-sided 1e-3 test after Bonferroni.
    let z = max_block_z(&a, &b);
    assert!(z <= 4.3, "animated frame 30 differs from the static scene at its time: max |z| {z:.2}");
    // The check has power: the static scene at frame 0 is rejected.
    let (start, _) = RenderScene::build(&scene.at_time(0.0), &builder, crate::common::tracing());
    let z0 = max_block_z(&a, &render(&start, 3, spp));
    assert!(z0 > 4.3, "frame 30 against frame 0 should differ, max |z| {z0:.2}");
}
