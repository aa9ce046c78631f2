//! Scenes: the TOML format and its loader (in progress).
