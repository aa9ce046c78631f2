//! The film: per-pixel accumulation (in progress).
