//! Arbor's benchmark lab, behind `bvh-bench` and the criterion benches: what is measured and how.
//!
//! - [`compare`]: the builder comparison: build time, SAH and trace speed on the same rays;
//! - [`rays`]: the ray sets trace speed is measured with (primary, shadow, diffuse);
//! - [`anim`]: ways of keeping a top-level BVH up to date through an animation;
//! - [`converge`]: image error against wall time, through [`arbor::device::Renderer`];
//! - [`peers`]: external builders (the obvhs crate's presets) in Arbor's layout, registered
//!   with the library's builder names by [`peers::register`].

pub mod anim;
pub mod compare;
pub mod converge;
pub mod peers;
pub mod rays;
