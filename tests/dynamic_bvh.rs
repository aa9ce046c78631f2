//! The dynamic BVH: deletion with dirty marking, the batched clean, insertion, local PRBVH and
//! the quality monitor, against `validate` after every operation.

use crate::common;

use arbor::bvh::dynamic::{DynamicBvh, DynamicConfig};
use arbor::bvh::{brute_force_closest, sah_cost};
use arbor::geometry::{Aabb, Triangle};
use common::{rng, unit_vec3};
use glam::Vec3;
use rand::RngExt;

fn random_box(rng: &mut common::Rng, size: f32) -> Aabb {
    let c = unit_vec3(rng) * 10.0;
    let h = unit_vec3(rng) * size + Vec3::splat(1e-3);
    Aabb::new(c - h, c + h)
}

/// Thousands of seeded random deletions, insertions and cleans, interleaved in any order, keep
/// every invariant, including "a dirty node's ancestors are dirty"; each clean visits exactly
/// the dirty nodes.
#[test]
fn random_interleaved_operations_keep_the_tree_valid() {
    for seed in 0..4 {
        let mut r = rng(seed);
        let n = [1, 2, 40, 300][seed as usize];
        let mut boxes: Vec<Aabb> = (0..n).map(|_| random_box(&mut r, 0.5)).collect();
        let mut tree = DynamicBvh::build(&boxes);
        tree.validate(&boxes).unwrap();
        let mut cleans = 0;
        for step in 0..2500 {
            let prim = r.random_range(0..n) as u32;
            match r.random_range(0..10) {
                0..=3 => {
                    let was_in = tree.contains(prim);
                    assert_eq!(tree.remove(prim), was_in);
                }
                4..=7 => {
                    if !tree.contains(prim) {
                        boxes[prim as usize] = random_box(&mut r, 0.5);
                        tree.insert(prim, boxes[prim as usize]);
                    }
                }
                _ => {
                    let dirty = tree.dirty_count();
                    assert_eq!(
                        tree.clean(),
                        dirty,
                        "seed {seed} step {step}: clean must visit exactly the dirty nodes"
                    );
                    assert!(!tree.is_dirty());
                    cleans += 1;
                }
            }
            if let Err(e) = tree.validate(&boxes) {
                panic!("seed {seed} step {step}: {e}");
            }
        }
        assert!(cleans > 100);
        // Put everything back: the clean tree is then a valid Bvh over all primitives.
        for p in 0..n as u32 {
            if !tree.contains(p) {
                tree.insert(p, boxes[p as usize]);
            }
        }
        tree.clean();
        tree.validate(&boxes).unwrap();
        assert_eq!(tree.prim_count(), n);
        arbor::bvh::validate(tree.bvh(), &boxes).unwrap();
    }
}

/// Deleting one leaf of a large tree dirties only its ancestors, and the clean visits only them:
/// the work follows the deletions, not the tree's size.
#[test]
fn clean_visits_only_the_dirty_path() {
    let mut r = rng(7);
    let boxes: Vec<Aabb> = (0..20_000).map(|_| random_box(&mut r, 0.05)).collect();
    let mut tree = DynamicBvh::build(&boxes);
    let nodes = tree.bvh().nodes.len();
    for p in [5u32, 77, 19_999] {
        // The leaf's depth is the number of ancestors that get marked.
        let mut depth = 0;
        let leaf = (0..tree.bvh().nodes.len())
            .find(|&i| i != 1 && tree.bvh().nodes[i].is_leaf() && tree.bvh().nodes[i].first == p)
            .unwrap();
        let mut a = tree.bvh().parents[leaf];
        while a != u32::MAX {
            depth += 1;
            a = tree.bvh().parents[a as usize];
        }
        tree.remove(p);
        assert_eq!(tree.dirty_count(), depth);
        let visits = tree.clean();
        assert_eq!(visits, depth);
        assert!(visits < 64, "a leaf at depth {depth} of a {nodes}-node tree");
        tree.insert(p, boxes[p as usize]);
        tree.validate(&boxes).unwrap();
    }
    // Cozzi's spatial locality: neighbours deleted together share most of their dirty path.
    let mut near: Vec<u32> = (0..boxes.len() as u32).collect();
    near.sort_by(|&a, &b| boxes[a as usize].center().x.total_cmp(&boxes[b as usize].center().x));
    let close = &near[..8];
    for &p in close {
        tree.remove(p);
    }
    let dirty = tree.dirty_count();
    assert_eq!(tree.clean(), dirty);
    assert!(dirty < 8 * 40, "{dirty} dirty nodes for 8 neighbouring deletions");
}

/// Frames of random motion through `update`: the tree stays valid, every primitive stays in it,
/// closest hits agree with brute force, and local PRBVH keeps the SAH no worse than insertion
/// alone.
#[test]
fn update_frames_keep_the_tree_valid_and_traversable() {
    let mut r = rng(11);
    let n = 2000;
    let mut tris: Vec<Triangle> = (0..n)
        .map(|_| {
            let c = unit_vec3(&mut r) * 10.0;
            Triangle::new(c, c + unit_vec3(&mut r) * 0.3, c + unit_vec3(&mut r) * 0.3)
        })
        .collect();
    let mut boxes: Vec<Aabb> = tris.iter().map(Triangle::aabb).collect();
    let config = DynamicConfig { check_every: 10, ..Default::default() };
    let mut tree = DynamicBvh::build(&boxes);
    let mut checks = 0;
    for frame in 0..40 {
        let mut moves = Vec::new();
        for _ in 0..100 {
            let p = r.random_range(0..n);
            if moves.iter().any(|&(q, _)| q == p as u32) {
                continue;
            }
            let d = (unit_vec3(&mut r) - 0.5) * 2.0;
            let t = &mut tris[p];
            *t = Triangle::new(t.v0 + d, t.v1 + d, t.v2 + d);
            boxes[p] = t.aabb();
            moves.push((p as u32, boxes[p]));
        }
        let stats = tree.update(&moves, &boxes, &config);
        checks += usize::from(stats.fresh_sah.is_some());
        tree.validate(&boxes).unwrap_or_else(|e| panic!("frame {frame}: {e}"));
        assert_eq!(tree.prim_count(), n);
        let exact = sah_cost(tree.bvh());
        assert!((stats.sah_estimate - exact).abs() <= 1e-4 * exact, "estimate {} vs {exact}", stats.sah_estimate);
    }
    assert!(checks >= 4, "the monitor checks every 10 updates");
    let rays = common::rays_at(&tree.bvh().bounds(), &tris.iter().map(|t| t.v0).collect::<Vec<_>>(), 2000, &mut r);
    for ray in &rays {
        let got = tree.bvh().closest_hit_triangles(&tris, ray, f32::INFINITY);
        assert_eq!(got, brute_force_closest(&tris, ray, f32::INFINITY));
    }
}

/// Local PRBVH lowers the SAH that insertion alone leaves, on the same motion.
#[test]
fn local_prbvh_improves_on_insertion_alone() {
    let run = |rounds: u32| {
        let mut r = rng(3);
        let n = 5000;
        let mut boxes: Vec<Aabb> = (0..n).map(|_| random_box(&mut r, 0.1)).collect();
        let no_monitor = DynamicConfig {
            prbvh_rounds: rounds,
            check_every: u32::MAX,
            rebuild_threshold: f64::INFINITY,
            ..Default::default()
        };
        let mut tree = DynamicBvh::build(&boxes);
        let mut reinsertions = 0;
        for _ in 0..30 {
            let moves: Vec<(u32, Aabb)> = (0..n as u32)
                .step_by(10)
                .map(|p| {
                    boxes[p as usize] = random_box(&mut r, 0.1);
                    (p, boxes[p as usize])
                })
                .collect();
            reinsertions += tree.update(&moves, &boxes, &no_monitor).reinsertions;
            tree.validate(&boxes).unwrap();
        }
        (sah_cost(tree.bvh()), reinsertions)
    };
    let (plain, none) = run(0);
    let (optimized, applied) = run(2);
    assert_eq!(none, 0);
    assert!(applied > 0);
    assert!(optimized < plain, "local PRBVH {optimized} vs insertion alone {plain}");
}

/// The monitor rebuilds a tree that motion has degraded past the threshold, and the rebuilt tree
/// has the fresh build's SAH.
#[test]
fn monitor_rebuilds_a_degraded_tree() {
    let mut r = rng(5);
    let n = 3000;
    let mut boxes: Vec<Aabb> = (0..n).map(|_| random_box(&mut r, 0.05)).collect();
    let config = DynamicConfig {
        prbvh_rounds: 0,
        check_every: 5,
        rebuild_threshold: 0.0,
        rebuild_fraction: 1.0,
        ..Default::default()
    };
    let mut tree = DynamicBvh::build(&boxes);
    let mut rebuilt = false;
    for _ in 0..20 {
        let moves: Vec<(u32, Aabb)> = (0..n as u32)
            .map(|p| {
                boxes[p as usize] = random_box(&mut r, 0.05);
                (p, boxes[p as usize])
            })
            .collect();
        let stats = tree.update(&moves, &boxes, &config);
        if stats.rebuilt {
            rebuilt = true;
            let fresh = stats.fresh_sah.unwrap();
            assert!((sah_cost(tree.bvh()) - fresh).abs() <= 1e-9 * fresh);
        }
        tree.validate(&boxes).unwrap();
    }
    assert!(rebuilt, "reinserting every primitive at random degrades the tree past a zero threshold");
}

/// Emptying the tree completely and refilling it works through every state.
#[test]
fn empty_and_refill() {
    let mut r = rng(9);
    let boxes: Vec<Aabb> = (0..16).map(|_| random_box(&mut r, 1.0)).collect();
    let mut tree = DynamicBvh::build(&boxes);
    for p in 0..16 {
        tree.remove(p);
    }
    tree.validate(&boxes).unwrap();
    tree.clean();
    assert!(tree.is_empty() && tree.bvh().nodes.is_empty());
    tree.validate(&boxes).unwrap();
    for p in (0..16).rev() {
        tree.insert(p, boxes[p as usize]);
        tree.validate(&boxes).unwrap();
    }
    tree.clean();
    arbor::bvh::validate(tree.bvh(), &boxes).unwrap();
}

/// When most primitives move, an update builds afresh rather than reinserting them one by one.
#[test]
fn a_mostly_moving_batch_is_rebuilt() {
    let mut r = rng(13);
    let n = 1000;
    let mut boxes: Vec<Aabb> = (0..n).map(|_| random_box(&mut r, 0.1)).collect();
    let mut tree = DynamicBvh::build(&boxes);
    let config = DynamicConfig::default();
    for (count, expect_rebuild) in [(100, false), (400, true)] {
        let moves: Vec<(u32, Aabb)> = (0..count as u32)
            .map(|p| {
                boxes[p as usize] = random_box(&mut r, 0.1);
                (p, boxes[p as usize])
            })
            .collect();
        let stats = tree.update(
            &moves,
            &boxes,
            &DynamicConfig { check_every: u32::MAX, rebuild_threshold: f64::INFINITY, ..config },
        );
        assert_eq!(stats.rebuilt, expect_rebuild, "{count} of {n} moved");
        tree.validate(&boxes).unwrap();
    }
}
