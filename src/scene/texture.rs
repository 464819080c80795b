//! Decoded material textures and bilinear sampling.

use std::sync::Arc;

use glam::{Vec2, Vec3, Vec4};

/// How texture coordinates outside [0, 1] are folded back (glTF sampler wrap modes).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum WrapMode {
    #[default]
    Repeat,
    MirroredRepeat,
    ClampToEdge,
}

/// A material's reference to a texture: which one, and where on a mesh it is read.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TextureRef {
    pub texture: usize,
    /// glTF `texCoord` (or `KHR_texture_transform`'s, which overrides it): 0 reads TEXCOORD_0,
    /// 1 TEXCOORD_1; livebake reads no higher set (TEXCOORD_0 instead, warned at load time).
    pub tex_coord: u32,
    /// `KHR_texture_transform`; identity without it.
    pub transform: UvTransform,
}

impl TextureRef {
    /// Texture `texture` read at TEXCOORD_0, untransformed.
    pub fn new(texture: usize) -> TextureRef {
        TextureRef { texture, tex_coord: 0, transform: UvTransform::IDENTITY }
    }

    /// Where the texture is read ([`TextureUv`]).
    pub fn uv(&self) -> TextureUv {
        TextureUv { set: self.tex_coord, transform: self.transform }
    }
}

/// `KHR_texture_transform`: the texture coordinates scaled, rotated and offset, in that
/// order — `uv' = T·R·S·uv` with R = [cos r, sin r; −sin r, cos r] — kept as the two rows of
/// that affine map.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct UvTransform {
    u: Vec3,
    v: Vec3,
}

impl Default for UvTransform {
    fn default() -> Self {
        UvTransform::IDENTITY
    }
}

impl UvTransform {
    pub const IDENTITY: UvTransform = UvTransform { u: Vec3::X, v: Vec3::Y };

    /// The extension's `offset`, `rotation` (radians) and `scale`.
    pub fn new(offset: Vec2, rotation: f32, scale: Vec2) -> UvTransform {
        let (sin, cos) = rotation.sin_cos();
        UvTransform {
            u: Vec3::new(cos * scale.x, sin * scale.y, offset.x),
            v: Vec3::new(-sin * scale.x, cos * scale.y, offset.y),
        }
    }

    pub fn is_finite(&self) -> bool {
        self.u.is_finite() && self.v.is_finite()
    }

    /// `uv` transformed; an identity transform returns it as it is (the same bits).
    #[inline]
    pub fn apply(&self, uv: Vec2) -> Vec2 {
        if *self == UvTransform::IDENTITY {
            return uv;
        }
        Vec2::new(self.u.dot(uv.extend(1.0)), self.v.dot(uv.extend(1.0)))
    }
}

/// Where a material's textures are read on a mesh: a TEXCOORD set, transformed
/// ([`Material::texture_uv`](super::Material::texture_uv)).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TextureUv {
    /// 1: TEXCOORD_1; any other value: TEXCOORD_0.
    pub set: u32,
    pub transform: UvTransform,
}

/// An 8-bit RGBA image. Colour textures in glTF (base colour, emissive) are sRGB-encoded;
/// sampling returns linear values.
#[derive(Clone, Debug)]
pub struct Texture {
    pub name: String,
    pub width: u32,
    pub height: u32,
    /// Row-major, top row first (glTF UV (0,0) is the top-left corner). Shared by the
    /// textures of one image (and by copies of the scene).
    pub rgba8: Arc<[[u8; 4]]>,
    pub srgb: bool,
    pub wrap_s: WrapMode,
    pub wrap_t: WrapMode,
}

/// The sRGB decoding of each 8-bit value (the GPU resolve uploads the same table).
pub fn srgb_to_linear_lut() -> &'static [f32; 256] {
    use std::sync::OnceLock;
    static LUT: OnceLock<[f32; 256]> = OnceLock::new();
    LUT.get_or_init(|| {
        let mut t = [0.0f32; 256];
        for (i, v) in t.iter_mut().enumerate() {
            let c = i as f32 / 255.0;
            *v = if c <= 0.04045 { c / 12.92 } else { ((c + 0.055) / 1.055).powf(2.4) };
        }
        t
    })
}

fn wrap(i: i64, n: u32, mode: WrapMode) -> u32 {
    let n = n as i64;
    let r = match mode {
        WrapMode::Repeat => i.rem_euclid(n),
        WrapMode::ClampToEdge => i.clamp(0, n - 1),
        WrapMode::MirroredRepeat => {
            let p = i.rem_euclid(2 * n);
            if p < n { p } else { 2 * n - 1 - p }
        }
    };
    r as u32
}

impl Texture {
    /// Linear value of texel (x, y) (alpha is never sRGB-encoded).
    #[inline]
    pub fn texel(&self, x: u32, y: u32) -> Vec4 {
        let [r, g, b, a] = self.rgba8[(y * self.width + x) as usize];
        if self.srgb {
            let lut = srgb_to_linear_lut();
            Vec4::new(lut[r as usize], lut[g as usize], lut[b as usize], a as f32 / 255.0)
        } else {
            Vec4::new(r as f32, g as f32, b as f32, a as f32) / 255.0
        }
    }

    /// Bilinear sample at `uv` with the texture's wrap modes. Filtering happens on linear values.
    pub fn sample(&self, uv: Vec2) -> Vec4 {
        if self.width == 0 || self.height == 0 {
            return Vec4::ONE;
        }
        let x = uv.x * self.width as f32 - 0.5;
        let y = uv.y * self.height as f32 - 0.5;
        if !x.is_finite() || !y.is_finite() {
            return self.texel(0, 0);
        }
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let (x0, y0) = (x0 as i64, y0 as i64);
        let xs = [wrap(x0, self.width, self.wrap_s), wrap(x0 + 1, self.width, self.wrap_s)];
        let ys = [wrap(y0, self.height, self.wrap_t), wrap(y0 + 1, self.height, self.wrap_t)];
        let top = self.texel(xs[0], ys[0]) * (1.0 - fx) + self.texel(xs[1], ys[0]) * fx;
        let bottom = self.texel(xs[0], ys[1]) * (1.0 - fx) + self.texel(xs[1], ys[1]) * fx;
        top * (1.0 - fy) + bottom * fy
    }

    /// Mean linear value over all texels (used to weight emitters with emissive textures).
    pub fn mean(&self) -> Vec4 {
        let mut sum = glam::DVec4::ZERO;
        for y in 0..self.height {
            for x in 0..self.width {
                sum += self.texel(x, y).as_dvec4();
            }
        }
        let n = (self.width as f64 * self.height as f64).max(1.0);
        (sum / n).as_vec4()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn checker() -> Texture {
        Texture {
            name: "c".into(),
            width: 2,
            height: 2,
            rgba8: vec![[255, 255, 255, 255], [0, 0, 0, 255], [0, 0, 0, 255], [255, 255, 255, 255]].into(),
            srgb: true,
            wrap_s: WrapMode::Repeat,
            wrap_t: WrapMode::Repeat,
        }
    }

    #[test]
    fn texel_centres_are_exact_and_srgb_decodes() {
        let t = checker();
        assert_eq!(t.sample(Vec2::new(0.25, 0.25)), Vec4::ONE);
        assert_eq!(t.sample(Vec2::new(0.75, 0.25)), Vec4::new(0.0, 0.0, 0.0, 1.0));
        // sRGB 188/255 decodes to ~0.5 linear.
        let mut g = checker();
        g.rgba8 = vec![[188, 188, 188, 255]; 4].into();
        assert!((g.sample(Vec2::splat(0.5)).x - 0.5029).abs() < 1e-3);
    }

    #[test]
    fn bilinear_midpoint_and_wrap_modes() {
        let t = checker();
        // Halfway between a white and a black texel (horizontally) and the wrap neighbour.
        let v = t.sample(Vec2::new(0.5, 0.25));
        assert!((v.x - 0.5).abs() < 1e-6);
        // Repeat: u = 1.25 is u = 0.25.
        assert_eq!(t.sample(Vec2::new(1.25, 0.25)), t.sample(Vec2::new(0.25, 0.25)));
        let mut c = checker();
        c.wrap_s = WrapMode::ClampToEdge;
        assert_eq!(c.sample(Vec2::new(-3.0, 0.25)), Vec4::ONE);
        assert_eq!(wrap(-1, 4, WrapMode::MirroredRepeat), 0);
        assert_eq!(wrap(4, 4, WrapMode::MirroredRepeat), 3);
        assert_eq!(wrap(5, 4, WrapMode::Repeat), 1);
    }
}
