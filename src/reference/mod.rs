//! CPU reference path tracer: the ground truth every other estimate is tested against.
