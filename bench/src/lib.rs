//! Arbor's benchmark lab, behind `bvh-bench` and the criterion benches: what is measured and how.
//!
//! - [`compare`]: the builder comparison: build time, SAH and trace speed on the same rays;
//! - [`rays`]: the ray sets trace speed is measured with (primary, shadow, diffuse);
//! - [`anim`]: ways of keeping a top-level BVH up to date through an animation;
//! - [`converge`]: image error against wall time, through [`arbor::device::Renderer`];
//! - `embree` (feature `embree`): Embree 3 as a peer, its own trees and traversal;
//! - [`peers`]: external builders (the obvhs crate's presets) in Arbor's layout, registered
//!   with the library's builder names by [`peers::register`].

pub mod anim;
pub mod compare;
pub mod converge;
#[cfg(feature = "embree")]
pub mod embree;
pub mod peers;
pub mod rays;

/// The median of `values` (the upper one of an even count), 0 for none: every time the lab
/// reports is the median of its runs, so that one slow spell of a shared machine does not move
/// it.
pub fn median(values: impl IntoIterator<Item = f64>) -> f64 {
    let mut v: Vec<f64> = values.into_iter().collect();
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(0.0)
}

#[cfg(test)]
mod tests {
    #[test]
    fn median_takes_the_middle_value() {
        assert_eq!(super::median([3.0, 1.0, 2.0]), 2.0);
        assert_eq!(super::median([4.0, 1.0, 3.0, 2.0]), 3.0);
        assert_eq!(super::median([]), 0.0);
    }
}
