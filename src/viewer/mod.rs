//! The viewer: a window onto a [`source::LightSource`] (the live runtime), drawn by the GPU renderer; also renders offscreen for screenshots and tests.

pub mod app;
pub mod camera;
pub mod render;
pub mod source;
pub mod xvfb;

pub use app::{FrameContext, ViewerError, ViewerLoop, ViewerOptions, ViewerReport, run};
pub use camera::Camera;
pub use render::{DrawSettings, Renderer};
pub use source::{LightSource, RuntimeLight, SceneState, SourceStatus};
