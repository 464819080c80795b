//! The live runtime (2017 thesis, 3.3.2): LOD 0 everywhere at first light, then the cells near
//! the camera refined in the background and swapped to the next LOD once converged.

pub mod shown;
