//! Image output (in progress).
