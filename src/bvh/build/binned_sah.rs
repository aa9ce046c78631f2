//! Top-down binned SAH builder: the classic reference that LBVH (and later PRBVH) is compared
//! against (Wald, "On fast construction of SAH-based bounding volume hierarchies", 2007).
//!
//! Each node bins its primitives' centroids into `bins` equal slots along each axis, sweeps the
//! bins to find the split with the lowest `A_left * N_left + A_right * N_right`, and partitions in
//! place. Subtrees above a size threshold are built in parallel (rayon `join`); node pairs are
//! allocated from an atomic counter, so the layout is siblings-adjacent like every [`Bvh`].
//! When the centroids cannot be separated (all in one bin, or all equal) the range is halved by
//! index, so a leaf never exceeds `max_leaf_size`.

use std::sync::atomic::{AtomicU32, Ordering};

use bytemuck::Zeroable;
use glam::Vec3;

use crate::bvh::parallel::SharedSlice;
use crate::bvh::sah::half_area_f64;
use crate::bvh::{Bvh, BvhNode, INVALID_INDEX, Nodes};
use crate::geometry::Aabb;

/// Options of [`build`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BinnedSahConfig {
    /// Bins per axis. Default 32.
    pub bins: usize,
    /// Ranges of at most this many primitives become leaves. Default 1, the same as LBVH, so
    /// both go through the same leaf collapse afterwards.
    pub max_leaf_size: u32,
    /// Ranges larger than this are split into parallel tasks. Default 4096.
    pub parallel_threshold: usize,
}

impl Default for BinnedSahConfig {
    fn default() -> Self {
        Self { bins: 32, max_leaf_size: 1, parallel_threshold: 4096 }
    }
}

struct Context<'a> {
    prim_aabbs: &'a [Aabb],
    centroids: Vec<Vec3>,
    config: BinnedSahConfig,
    nodes: SharedSlice<'a, BvhNode>,
    parents: SharedSlice<'a, u32>,
    next: AtomicU32,
}

/// Builds a tree over primitives given by their boxes.
pub fn build(prim_aabbs: &[Aabb], config: &BinnedSahConfig) -> Bvh {
    assert!(config.bins >= 2 && config.max_leaf_size >= 1, "binned SAH needs 2+ bins and leaves of 1+");
    let n = prim_aabbs.len();
    if n <= 1 {
        return Bvh::single_leaf(prim_aabbs);
    }
    // Slot 0 is the root, slot 1 the padding; pairs are allocated from 2 on.
    let mut nodes: Nodes = vec![BvhNode::zeroed(); 2 * n].into();
    let mut parents = vec![INVALID_INDEX; 2 * n];
    let mut prim_ids: Vec<u32> = (0..n as u32).collect();
    let used = {
        let ctx = Context {
            prim_aabbs,
            centroids: prim_aabbs.iter().map(Aabb::center).collect(),
            config: *config,
            nodes: SharedSlice::new(&mut nodes),
            parents: SharedSlice::new(&mut parents),
            next: AtomicU32::new(2),
        };
        build_node(&ctx, 0, &mut prim_ids, 0);
        ctx.next.load(Ordering::Relaxed) as usize
    };
    nodes.truncate(used);
    parents.truncate(used);
    Bvh { nodes, parents, prim_ids }
}

/// Builds the subtree of `ids` (which start at `offset` in `prim_ids`) into node `slot`.
fn build_node(ctx: &Context, slot: u32, ids: &mut [u32], offset: u32) {
    let bounds = ids.iter().fold(Aabb::EMPTY, |b, &p| b.union(ctx.prim_aabbs[p as usize]));
    if ids.len() <= ctx.config.max_leaf_size as usize {
        // SAFETY: every slot is handed to exactly one call of build_node.
        unsafe { ctx.nodes.set(slot as usize, BvhNode::leaf(bounds, offset, ids.len() as u32)) };
        return;
    }
    let mid = partition(ctx, ids);
    let left = ctx.next.fetch_add(2, Ordering::Relaxed);
    // SAFETY: `slot` belongs to this call; `left` and `left + 1` were just allocated to it.
    unsafe {
        ctx.nodes.set(slot as usize, BvhNode::internal(bounds, left));
        ctx.parents.set(left as usize, slot);
        ctx.parents.set(left as usize + 1, slot);
    }
    let (l, r) = ids.split_at_mut(mid);
    let right_offset = offset + mid as u32;
    if l.len() + r.len() > ctx.config.parallel_threshold {
        rayon::join(|| build_node(ctx, left, l, offset), || build_node(ctx, left + 1, r, right_offset));
    } else {
        build_node(ctx, left, l, offset);
        build_node(ctx, left + 1, r, right_offset);
    }
}

/// Reorders `ids` so that the best binned split separates `ids[..mid]` from `ids[mid..]`, and
/// returns `mid` (in `1..ids.len()`).
fn partition(ctx: &Context, ids: &mut [u32]) -> usize {
    let cb = ids.iter().fold(Aabb::EMPTY, |b, &p| b.grow(ctx.centroids[p as usize]));
    let extent = cb.extent();
    let bins = ctx.config.bins;
    // In f64: in f32, `bins / extent` overflows below an extent of about 1e-37, and every
    // centroid but the lowest went to the last bin, so each split peeled off one primitive and
    // the recursion overflowed the stack.
    let bin_of = |axis: usize, p: u32| -> usize {
        let scale = bins as f64 / f64::from(extent[axis]);
        let offset = f64::from(ctx.centroids[p as usize][axis]) - f64::from(cb.min[axis]);
        ((offset * scale) as usize).min(bins - 1)
    };
    // (cost, axis, first bin of the right side). Costs are in f64: f32 areas overflow for boxes
    // of extent beyond about 1e19 and underflow below about 1e-19, which made every split cost
    // the same (infinite or zero) on such scenes.
    let mut best: Option<(f64, usize, usize)> = None;
    for axis in 0..3 {
        if extent[axis].is_nan() || extent[axis] <= 0.0 {
            continue;
        }
        let mut count = vec![0u32; bins];
        let mut boxes = vec![Aabb::EMPTY; bins];
        for &p in ids.iter() {
            let b = bin_of(axis, p);
            count[b] += 1;
            boxes[b] = boxes[b].union(ctx.prim_aabbs[p as usize]);
        }
        // Right-to-left sweep stores the right side's cost for each split.
        let mut right_cost = vec![0.0f64; bins];
        let (mut acc_box, mut acc_n) = (Aabb::EMPTY, 0u32);
        for b in (1..bins).rev() {
            acc_box = acc_box.union(boxes[b]);
            acc_n += count[b];
            right_cost[b] = half_area_f64(&acc_box) * acc_n as f64;
        }
        let (mut acc_box, mut acc_n) = (Aabb::EMPTY, 0u32);
        for b in 1..bins {
            acc_box = acc_box.union(boxes[b - 1]);
            acc_n += count[b - 1];
            if acc_n == 0 || acc_n as usize == ids.len() {
                continue;
            }
            let cost = half_area_f64(&acc_box) * acc_n as f64 + right_cost[b];
            if best.is_none_or(|(c, _, _)| cost < c) {
                best = Some((cost, axis, b));
            }
        }
    }
    let Some((_, axis, split)) = best else {
        return ids.len() / 2;
    };
    // Two-pointer partition: left side keeps bins below `split`.
    let (mut i, mut j) = (0, ids.len());
    while i < j {
        if bin_of(axis, ids[i]) < split {
            i += 1;
        } else {
            j -= 1;
            ids.swap(i, j);
        }
    }
    i
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_tree_does_not_depend_on_the_units() {
        crate::bvh::assert_scale_invariant("binned-sah", |p| build(p, &BinnedSahConfig::default()));
    }

    /// At 2^-120 (about 1e-36) `bins / extent` overflows f32: every split peeled off one
    /// primitive and 20,000 of them overflowed the stack. The bins are now computed in f64,
    /// and the tree is the unit-scale one.
    #[test]
    fn a_tiny_scene_gets_the_same_tree() {
        let unit = crate::bvh::scattered_boxes(2000, 0.3);
        let tiny: Vec<Aabb> = unit.iter().map(|b| b.scaled(2f32.powi(-120))).collect();
        let (a, b) = (build(&unit, &Default::default()), build(&tiny, &Default::default()));
        crate::bvh::validate(&b, &tiny).unwrap();
        assert_eq!(a.prim_ids, b.prim_ids);
        assert!(a.nodes.iter().zip(b.nodes.iter()).all(|(x, y)| (x.first, x.prim_count) == (y.first, y.prim_count)));
    }
}
