//! Viewer cameras: free-fly (WASD + mouse look) and orbit, their matrices, and start poses.

use glam::{Mat4, Vec3};

use crate::scene::{Projection, Scene};

/// How the mouse and keys move the camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum CameraMode {
    /// Mouse looks around the eye; WASD moves, Q/E down/up.
    FreeFly,
    /// Mouse turns the eye around `target` at its distance; W/S move closer/further.
    Orbit,
}

#[derive(Clone, Debug)]
pub struct Camera {
    pub eye: Vec3,
    /// Radians about +Y; 0 looks along −Z.
    pub yaw: f32,
    /// Radians above the horizon.
    pub pitch: f32,
    /// Vertical field of view, radians.
    pub yfov: f32,
    /// Orbit centre (also the distance orbit keeps).
    pub target: Vec3,
    pub mode: CameraMode,
    /// Metres per second for free-fly moves.
    pub speed: f32,
    pub znear: f32,
    pub zfar: f32,
}

const MAX_PITCH: f32 = 1.55;

impl Camera {
    /// A camera at `eye` looking at `target`.
    pub fn look_at(eye: Vec3, target: Vec3, yfov: f32, scene_size: f32) -> Camera {
        let d = target - eye;
        let f = if d.length_squared() > 0.0 { d.normalize() } else { Vec3::NEG_Z };
        let size = scene_size.max(1e-3);
        Camera {
            eye,
            yaw: f.x.atan2(-f.z),
            pitch: f.y.clamp(-1.0, 1.0).asin().clamp(-MAX_PITCH, MAX_PITCH),
            yfov,
            target,
            mode: CameraMode::FreeFly,
            speed: 0.25 * size,
            znear: (size * 1e-3).max(1e-3),
            zfar: size * 20.0,
        }
    }

    /// The start pose: the file's first perspective camera, else a view framing the
    /// scene's bounds from +Z (slightly above).
    pub fn initial(scene: &Scene) -> Camera {
        let (lo, hi) = scene.bounds().unwrap_or((Vec3::splat(-1.0), Vec3::splat(1.0)));
        let size = (hi - lo).length().max(1e-3);
        for c in &scene.cameras {
            if let Projection::Perspective { yfov, .. } = c.projection {
                let forward = c.rotation * Vec3::NEG_Z;
                return Camera::look_at(c.position, c.position + forward * (0.5 * size), yfov, size);
            }
        }
        Camera::framing(lo, hi)
    }

    /// A camera on +Z of the box `lo..hi`, far enough that the box's bounding sphere fits.
    pub fn framing(lo: Vec3, hi: Vec3) -> Camera {
        let centre = 0.5 * (lo + hi);
        let radius = (0.5 * (hi - lo).length()).max(1e-3);
        let yfov = 50f32.to_radians();
        let distance = radius / (0.5 * yfov).sin();
        let dir = Vec3::new(0.0, 0.25, 1.0).normalize();
        Camera::look_at(centre + dir * distance, centre, yfov, 2.0 * radius)
    }

    pub fn forward(&self) -> Vec3 {
        let (sy, cy) = self.yaw.sin_cos();
        let (sp, cp) = self.pitch.sin_cos();
        Vec3::new(cp * sy, sp, -cp * cy)
    }

    pub fn right(&self) -> Vec3 {
        self.forward().cross(Vec3::Y).normalize_or(Vec3::X)
    }

    /// The point looked at: the orbit target in orbit mode, one metre ahead otherwise.
    pub fn look_target(&self) -> Vec3 {
        match self.mode {
            CameraMode::Orbit => self.target,
            CameraMode::FreeFly => self.eye + self.forward(),
        }
    }

    /// World → clip (wgpu depth range 0..1) for an eye displaced `offset` metres to the
    /// right (stereo), at `aspect` = width/height.
    pub fn view_proj(&self, aspect: f32, offset: f32) -> Mat4 {
        let shift = self.right() * offset;
        let view = glam::camera::rh::view::look_at_mat4(self.eye + shift, self.eye + shift + self.forward(), Vec3::Y);
        // WebGPU's clip space is DirectX's: depth 0..1, y up.
        glam::camera::rh::proj::directx::perspective(self.yfov, aspect.max(1e-3), self.znear, self.zfar) * view
    }

    /// Mouse motion in pixels: turns the view (free-fly) or the eye around the target (orbit).
    pub fn turn(&mut self, dx: f32, dy: f32) {
        const RADIANS_PER_PIXEL: f32 = 0.003;
        let distance = (self.target - self.eye).length();
        self.yaw += dx * RADIANS_PER_PIXEL;
        self.pitch = (self.pitch - dy * RADIANS_PER_PIXEL).clamp(-MAX_PITCH, MAX_PITCH);
        if self.mode == CameraMode::Orbit {
            self.eye = self.target - self.forward() * distance;
        }
    }

    /// Moves by `dir` (x right, y up, z forward; each −1..1) for `seconds`.
    pub fn travel(&mut self, dir: Vec3, seconds: f32) {
        let step = self.speed * seconds;
        match self.mode {
            CameraMode::FreeFly => {
                self.eye += (self.right() * dir.x + Vec3::Y * dir.y + self.forward() * dir.z) * step;
            }
            CameraMode::Orbit => {
                let distance = ((self.target - self.eye).length() - dir.z * step).max(self.znear * 10.0);
                self.eye = self.target - self.forward() * distance;
            }
        }
    }

    /// Switches free-fly ↔ orbit; orbit turns around the point the view centre looks at,
    /// at the current distance to the last target.
    pub fn toggle_mode(&mut self) {
        self.mode = match self.mode {
            CameraMode::FreeFly => {
                let distance = (self.target - self.eye).length().max(self.znear * 10.0);
                self.target = self.eye + self.forward() * distance;
                CameraMode::Orbit
            }
            CameraMode::Orbit => CameraMode::FreeFly,
        };
    }

    /// One wheel notch up (positive) or down: free-fly speed ×/÷ 1.25.
    pub fn change_speed(&mut self, notches: f32) {
        self.speed = (self.speed * 1.25f32.powf(notches)).clamp(1e-3, 1e4);
    }
}

/// Parses `--camera EX,EY,EZ,TX,TY,TZ`.
pub fn parse_pose(s: &str) -> Result<(Vec3, Vec3), String> {
    let v: Vec<f32> =
        s.split(',').map(|p| p.trim().parse::<f32>().map_err(|e| format!("{p:?}: {e}"))).collect::<Result<_, _>>()?;
    if v.len() != 6 || v.iter().any(|x| !x.is_finite()) {
        return Err(format!("expected six finite numbers EX,EY,EZ,TX,TY,TZ, got {s:?}"));
    }
    let (eye, target) = (Vec3::new(v[0], v[1], v[2]), Vec3::new(v[3], v[4], v[5]));
    if eye == target {
        return Err("the eye and the target must differ".into());
    }
    Ok((eye, target))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn look_at_points_the_view_at_the_target() {
        let c = Camera::look_at(Vec3::new(1.0, 2.0, 5.0), Vec3::new(1.0, 1.0, 0.0), 1.0, 2.0);
        let want = (Vec3::new(1.0, 1.0, 0.0) - Vec3::new(1.0, 2.0, 5.0)).normalize();
        assert!(c.forward().distance(want) < 1e-5);
        // The target projects to the image centre.
        let clip = c.view_proj(1.5, 0.0) * Vec3::new(1.0, 1.0, 0.0).extend(1.0);
        assert!((clip.x / clip.w).abs() < 1e-5 && (clip.y / clip.w).abs() < 1e-5);
    }

    #[test]
    fn orbit_keeps_the_distance_to_the_target() {
        let mut c = Camera::look_at(Vec3::new(0.0, 0.0, 4.0), Vec3::ZERO, 1.0, 2.0);
        c.toggle_mode();
        c.turn(120.0, -40.0);
        assert!((c.eye.length() - 4.0).abs() < 1e-4);
        assert!(c.forward().distance(-c.eye.normalize()) < 1e-4);
    }

    #[test]
    fn framing_sees_the_whole_box() {
        let (lo, hi) = (Vec3::new(-1.0, 0.0, -3.0), Vec3::new(2.0, 1.0, 0.5));
        let c = Camera::framing(lo, hi);
        let m = c.view_proj(1.0, 0.0);
        for i in 0..8 {
            let p = Vec3::new([lo.x, hi.x][i & 1], [lo.y, hi.y][(i >> 1) & 1], [lo.z, hi.z][i >> 2]);
            let q = m * p.extend(1.0);
            let ndc = q.truncate() / q.w;
            assert!(ndc.x.abs() <= 1.0 && ndc.y.abs() <= 1.0 && (0.0..=1.0).contains(&ndc.z), "{p} -> {ndc}");
        }
    }

    #[test]
    fn pose_parses_and_refuses_nonsense() {
        assert_eq!(parse_pose("1,2,3,4,5,6").unwrap(), (Vec3::new(1.0, 2.0, 3.0), Vec3::new(4.0, 5.0, 6.0)));
        assert!(parse_pose("1,2,3").is_err());
        assert!(parse_pose("1,2,3,1,2,3").is_err());
        assert!(parse_pose("a,2,3,4,5,6").is_err());
    }
}
