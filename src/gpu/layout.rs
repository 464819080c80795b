//! `#[repr(C)]` mirrors of the WGSL structs the CPU uploads. Each is checked field by field
//! against naga's layout of the shader's struct (tests below): a change on one side that the
//! other misses fails there, not as garbage on screen.

use bytemuck::{Pod, Zeroable};

/// Most light-map LODs the GPU mirror holds (`MAX_LODS` in lightmap.inc.wgsl).
pub const MAX_LODS: usize = 8;

/// What the surface pass shows (`VIEW_*` in common.inc.wgsl).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[repr(u32)]
pub enum ViewMode {
    /// albedo × E/π + emission.
    #[default]
    Lit = 0,
    /// Each cell tinted by its shown LOD.
    CellLod = 1,
    /// Cell faces drawn as dark lines.
    CellGrid = 2,
    /// E/π alone (a white, non-emitting surface).
    Irradiance = 3,
    /// A checker of the shown LOD's texels.
    TexelChecker = 4,
}

impl ViewMode {
    pub const ALL: [ViewMode; 5] =
        [ViewMode::Lit, ViewMode::CellLod, ViewMode::CellGrid, ViewMode::Irradiance, ViewMode::TexelChecker];

    pub fn name(self) -> &'static str {
        match self {
            ViewMode::Lit => "lit",
            ViewMode::CellLod => "cell LOD",
            ViewMode::CellGrid => "cell grid",
            ViewMode::Irradiance => "irradiance",
            ViewMode::TexelChecker => "texel checker",
        }
    }
}

/// `FrameUniforms` (common.inc.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct FrameUniforms {
    pub view_proj: [[f32; 4]; 4],
    pub inv_view_proj: [[f32; 4]; 4],
    pub eye: [f32; 3],
    pub exposure: f32,
    pub view_mode: u32,
    pub _pad0: u32,
    pub _pad1: u32,
    pub _pad2: u32,
}

/// `LodLevel` (lightmap.inc.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable, PartialEq)]
pub struct LodLevel {
    pub pages_x: u32,
    pub pages_y: u32,
    pub table_offset: u32,
    pub _pad: u32,
}

/// `LightmapParams` (lightmap.inc.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable, PartialEq)]
pub struct LightmapParams {
    pub grid_origin: [f32; 3],
    pub cell_size: f32,
    pub grid_dims: [u32; 3],
    pub lod_count: u32,
    pub atlas_size: [u32; 2],
    pub blend_band: f32,
    pub pool_columns: u32,
    pub layer_count: u32,
    pub cell_count: u32,
    pub _pad0: u32,
    pub _pad1: u32,
    /// Per layer, per LOD (`layer · MAX_LODS + lod`).
    pub levels: [LodLevel; 2 * MAX_LODS],
}

/// `MaterialUniforms` (surface.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct MaterialUniforms {
    pub base_color: [f32; 4],
    pub emission: [f32; 3],
    /// `MASK`'s cutoff: a cut-out fragment's alpha is below it (0 for other modes).
    pub alpha_cutoff: f32,
    /// 1 for `BLEND`: alpha is the surface's coverage.
    pub blend: u32,
    /// `KHR_materials_transmission` factor.
    pub transmission: f32,
    pub _pad0: u32,
    pub _pad1: u32,
}

/// `ProbePoint` (irradiance_probe.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct ProbePoint {
    pub position: [f32; 3],
    pub _pad0: f32,
    pub uv: [f32; 2],
    pub _pad1: [f32; 2],
}

/// `AnalysisParams` (bundle_analysis.wgsl): one direction's frame and analysis window.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable, PartialEq)]
pub struct AnalysisParams {
    pub t: [f32; 3],
    pub pixel: f32,
    pub b: [f32; 3],
    pub res: u32,
    pub origin: [f32; 2],
    pub drawn_count: u32,
    pub view_side: u32,
}

/// `MipLevel` (bundle_mips.wgsl): one reduction step, element offsets into the mip buffers.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable, PartialEq)]
pub struct MipLevel {
    pub src: u32,
    pub dst: u32,
    pub dst_side: u32,
    pub _pad: u32,
}

/// `TilePassParams` (bundle_tiles.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable, PartialEq)]
pub struct TilePassParams {
    pub side: u32,
    pub top_level: u32,
    pub capacity: u32,
    pub _pad: u32,
}

/// `PlannedTile` (bundle_tiles.wgsl): a tile as Program 1 appends it.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable, PartialEq, Eq)]
pub struct PlannedTile {
    pub level: u32,
    pub x: u32,
    pub y: u32,
    pub res: u32,
}

/// `ListParams` (bundle_lists.wgsl): one tile rectangle's raster into linked lists.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable, PartialEq)]
pub struct ListParams {
    pub t: [f32; 3],
    pub pixel: f32,
    pub b: [f32; 3],
    pub capacity: u32,
    pub dir: [f32; 3],
    pub width: u32,
    pub origin: [f32; 2],
    pub offset: [u32; 2],
    pub height: u32,
    pub view_side: u32,
    pub drawn_count: u32,
    pub _pad: u32,
}

/// `ResolveParams` (bundle_resolve.wgsl): one built rectangle's resolve.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable, PartialEq)]
pub struct ResolveParams {
    pub t: [f32; 3],
    pub pixel: f32,
    pub b: [f32; 3],
    pub pixel_area: f32,
    pub dir: [f32; 3],
    pub capacity: u32,
    /// Seen by lines' last sides looking along +ω (the sky in direction ω).
    pub sky_ahead: [f32; 3],
    pub rounding: f32,
    pub origin: [f32; 2],
    pub offset: [u32; 2],
    pub width: u32,
    pub height: u32,
    pub stacked: f32,
    pub snap: f32,
    pub lod_scale: f32,
    pub table_count: u32,
    pub whole_table: u32,
    pub texel_count: u32,
    pub weight_scale: f32,
    pub radiance_scale: f32,
    pub _pad0: u32,
    pub _pad1: u32,
    /// Seen by lines' first sides looking along −ω (the sky in direction −ω).
    pub sky_behind: [f32; 3],
    pub opaque_zero: u32,
}

/// `ResolveTriangle` (bundle_resolve.wgsl): a triangle's normal and faces.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable, PartialEq)]
pub struct ResolveTriangle {
    pub normal: [f32; 3],
    pub front_chart: u32,
    /// Per corner: front face UV (x, y), back face UV (z, w), LOD-0 texels.
    pub corner_uv: [[f32; 4]; 3],
    pub back_chart: u32,
    pub _pad0: u32,
    pub _pad1: u32,
    pub _pad2: u32,
}

/// `TableHeader` (bundle_resolve.wgsl): one texel table's rectangle and entries.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable, PartialEq, Eq)]
pub struct TableHeader {
    pub chart: u32,
    pub x0: i32,
    pub y0: i32,
    pub x1: i32,
    pub y1: i32,
    pub blocks_x: u32,
    pub first: u32,
    pub _pad: u32,
}

/// `SurfaceTriangle` (surface_radiance.inc.wgsl): what a triangle's material reads.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable, PartialEq)]
pub struct SurfaceTriangle {
    /// TEXCOORD_0 of the corners.
    pub uv0: [[f32; 2]; 3],
    pub material: u32,
    /// 1 when the triangle's emission travels with the global bundles.
    pub carried: u32,
    /// Its corners' vertex colours: `surface_colors[colors..colors + 3]`, or `NO_COLOR`.
    pub colors: u32,
    pub _pad: u32,
}

/// `SurfaceMaterial` (surface_radiance.inc.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable, PartialEq)]
pub struct SurfaceMaterial {
    /// Linear base-colour factor; alpha is the coverage factor.
    pub base_color: [f32; 4],
    pub emission: [f32; 3],
    pub double_sided: u32,
    /// Texture indices, `u32::MAX` for none.
    pub base_texture: u32,
    pub emissive_texture: u32,
    /// `ALPHA_*` in the shader (`scene::AlphaMode`), and `MASK`'s cutoff.
    pub alpha_mode: u32,
    pub alpha_cutoff: f32,
    /// `KHR_materials_transmission`'s factor and texture (its red channel).
    pub transmission: f32,
    pub transmission_texture: u32,
    /// 1 when light may pass the surface (`Material::lets_light_through`).
    pub passing: u32,
    pub _pad: u32,
}

/// `TextureHeader` (surface_radiance.inc.wgsl): one RGBA8 texture in the texel buffer.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable, PartialEq, Eq)]
pub struct TextureHeader {
    pub width: u32,
    pub height: u32,
    pub first: u32,
    pub srgb: u32,
    pub wrap_s: u32,
    pub wrap_t: u32,
    pub _pad0: u32,
    pub _pad1: u32,
}

/// One corner of a drawn triangle (vertex buffer; `VertexInput` in surface.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable, PartialEq)]
pub struct SurfaceVertex {
    pub position: [f32; 3],
    pub uv0: [f32; 2],
    /// Atlas UV (LOD-0 texels) of the front face; negative when the triangle has none.
    pub lightmap_front: [f32; 2],
    /// Atlas UV of the back face; negative when the triangle has none.
    pub lightmap_back: [f32; 2],
    /// Vertex colour (COLOR_0 as [`crate::scene::color_unorm16`] holds it); white where the
    /// mesh has none.
    pub color: [u16; 4],
}

impl SurfaceVertex {
    pub const ATTRIBUTES: [wgpu::VertexAttribute; 5] = wgpu::vertex_attr_array![
        0 => Float32x3, 1 => Float32x2, 2 => Float32x2, 3 => Float32x2, 4 => Unorm16x4
    ];

    pub fn buffer_layout() -> wgpu::VertexBufferLayout<'static> {
        wgpu::VertexBufferLayout {
            array_stride: std::mem::size_of::<SurfaceVertex>() as u64,
            step_mode: wgpu::VertexStepMode::Vertex,
            attributes: &Self::ATTRIBUTES,
        }
    }
}

#[cfg(test)]
mod tests {
    use std::mem::{offset_of, size_of};

    use super::*;
    use crate::gpu::shader;

    /// naga's layout of struct `name` in pass `pass`: its size and each member's offset.
    fn wgsl_layout(pass: &str, name: &str) -> (u32, Vec<(String, u32)>) {
        let text = shader::source(pass).unwrap();
        let module = naga::front::wgsl::parse_str(&text).unwrap();
        let mut layouter = naga::proc::Layouter::default();
        layouter.update(module.to_ctx()).unwrap();
        let (handle, ty) = module
            .types
            .iter()
            .find(|(_, t)| t.name.as_deref() == Some(name))
            .unwrap_or_else(|| panic!("no struct {name} in {pass}"));
        let naga::TypeInner::Struct { members, span } = &ty.inner else { panic!("{name} is not a struct") };
        assert_eq!(layouter[handle].size, *span);
        (*span, members.iter().map(|m| (m.name.clone().unwrap_or_default(), m.offset)).collect())
    }

    /// The integer constant `name` of pass `pass`.
    fn wgsl_const(pass: &str, name: &str) -> i64 {
        let module = naga::front::wgsl::parse_str(&shader::source(pass).unwrap()).unwrap();
        let (_, c) = module
            .constants
            .iter()
            .find(|(_, c)| c.name.as_deref() == Some(name))
            .unwrap_or_else(|| panic!("no const {name} in {pass}"));
        match module.global_expressions[c.init] {
            naga::Expression::Literal(naga::Literal::I32(v)) => v as i64,
            naga::Expression::Literal(naga::Literal::U32(v)) => v as i64,
            ref e => panic!("{name} is {e:?}"),
        }
    }

    /// The shader's page side and LOD count are the host's.
    #[test]
    fn lightmap_constants_match_the_host() {
        assert_eq!(wgsl_const("irradiance_probe.wgsl", "PAGE_SIDE"), crate::runtime::shown::PAGE_SIDE as i64);
        assert_eq!(wgsl_const("irradiance_probe.wgsl", "MAX_LODS"), MAX_LODS as i64);
    }

    macro_rules! assert_layout {
        ($pass:expr, $ty:ty, $wgsl:expr, [$($field:ident),* $(,)?]) => {{
            let (size, members) = wgsl_layout($pass, $wgsl);
            let rust: Vec<(String, u32)> = vec![$((stringify!($field).to_string(), offset_of!($ty, $field) as u32)),*];
            assert_eq!(rust, members, "{} member offsets", $wgsl);
            assert_eq!(size_of::<$ty>() as u32, size, "{} size", $wgsl);
        }};
    }

    #[test]
    fn uniform_structs_match_the_shaders() {
        assert_layout!(
            "surface.wgsl",
            FrameUniforms,
            "FrameUniforms",
            [view_proj, inv_view_proj, eye, exposure, view_mode, _pad0, _pad1, _pad2]
        );
        assert_layout!(
            "surface.wgsl",
            MaterialUniforms,
            "MaterialUniforms",
            [base_color, emission, alpha_cutoff, blend, transmission, _pad0, _pad1]
        );
        assert_layout!("surface.wgsl", LodLevel, "LodLevel", [pages_x, pages_y, table_offset, _pad]);
        assert_layout!(
            "surface.wgsl",
            LightmapParams,
            "LightmapParams",
            [
                grid_origin,
                cell_size,
                grid_dims,
                lod_count,
                atlas_size,
                blend_band,
                pool_columns,
                layer_count,
                cell_count,
                _pad0,
                _pad1,
                levels
            ]
        );
        assert_layout!("irradiance_probe.wgsl", ProbePoint, "ProbePoint", [position, _pad0, uv, _pad1]);
        assert_layout!(
            "bundle_analysis.wgsl",
            AnalysisParams,
            "AnalysisParams",
            [t, pixel, b, res, origin, drawn_count, view_side]
        );
        assert_layout!("bundle_mips.wgsl", MipLevel, "MipLevel", [src, dst, dst_side, _pad]);
        assert_layout!("bundle_tiles.wgsl", TilePassParams, "TilePassParams", [side, top_level, capacity, _pad]);
        assert_layout!("bundle_tiles.wgsl", PlannedTile, "PlannedTile", [level, x, y, res]);
        assert_layout!(
            "bundle_lists.wgsl",
            ListParams,
            "ListParams",
            [t, pixel, b, capacity, dir, width, origin, offset, height, view_side, drawn_count, _pad]
        );
        assert_layout!(
            "bundle_resolve.wgsl",
            ResolveParams,
            "ResolveParams",
            [
                t,
                pixel,
                b,
                pixel_area,
                dir,
                capacity,
                sky_ahead,
                rounding,
                origin,
                offset,
                width,
                height,
                stacked,
                snap,
                lod_scale,
                table_count,
                whole_table,
                texel_count,
                weight_scale,
                radiance_scale,
                _pad0,
                _pad1,
                sky_behind,
                opaque_zero
            ]
        );
        assert_layout!(
            "bundle_resolve.wgsl",
            SurfaceTriangle,
            "SurfaceTriangle",
            [uv0, material, carried, colors, _pad]
        );
        assert_layout!(
            "bundle_resolve.wgsl",
            SurfaceMaterial,
            "SurfaceMaterial",
            [
                base_color,
                emission,
                double_sided,
                base_texture,
                emissive_texture,
                alpha_mode,
                alpha_cutoff,
                transmission,
                transmission_texture,
                passing,
                _pad
            ]
        );
        assert_layout!(
            "bundle_resolve.wgsl",
            TextureHeader,
            "TextureHeader",
            [width, height, first, srgb, wrap_s, wrap_t, _pad0, _pad1]
        );
        assert_layout!(
            "bundle_resolve.wgsl",
            ResolveTriangle,
            "ResolveTriangle",
            [normal, front_chart, corner_uv, back_chart, _pad0, _pad1, _pad2]
        );
        assert_layout!(
            "bundle_resolve.wgsl",
            TableHeader,
            "TableHeader",
            [chart, x0, y0, x1, y1, blocks_x, first, _pad]
        );
    }

    /// The vertex buffer's attributes sit where the Rust struct's fields are.
    #[test]
    fn vertex_attributes_match_the_struct() {
        let offsets: Vec<u64> = SurfaceVertex::ATTRIBUTES.iter().map(|a| a.offset).collect();
        let fields = [
            offset_of!(SurfaceVertex, position),
            offset_of!(SurfaceVertex, uv0),
            offset_of!(SurfaceVertex, lightmap_front),
            offset_of!(SurfaceVertex, lightmap_back),
            offset_of!(SurfaceVertex, color),
        ];
        assert_eq!(offsets, fields.map(|f| f as u64));
    }
}
