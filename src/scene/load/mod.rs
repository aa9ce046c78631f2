//! Turning a parsed scene file into a checked [`super::Scene`].

mod objects;

pub(super) use objects::{invertible, load, parse};
