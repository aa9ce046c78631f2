//! Materials: BSDF sampling and evaluation (in progress).
