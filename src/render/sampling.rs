//! Sampling routines (in progress).
