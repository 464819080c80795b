//! The live runtime.
//!
//! STAND-IN on the `viewer` branch: only the shown light map's data types (to the lead's
//! specification); replaced by main's runtime at the merge.

pub mod shown;
