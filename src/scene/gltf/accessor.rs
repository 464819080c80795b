//! Bounds-checked accessor reading: component types (with glTF's normalisation rules),
//! `byteOffset`, `byteStride`, accessors without a bufferView (zeros) and sparse accessors.
//! Every size from the file goes through checked arithmetic before it is used.

use ::gltf::json;
use glam::{Vec2, Vec3, Vec4};
use json::accessor::{ComponentType, Type};
use json::validation::Checked;

use super::{Ctx, LoadError};

/// An accessor without a bufferView is `count` zeros that we must allocate ourselves; no
/// bytes in the file back that count, so cap it (16 M elements) to keep a lying file from
/// asking for terabytes.
pub(super) const MAX_SYNTHETIC_ELEMENTS: usize = 1 << 24;

/// How the elements of one accessor are encoded.
#[derive(Clone, Copy, Debug)]
struct Format {
    component: ComponentType,
    components: usize,
    normalized: bool,
}

impl Format {
    fn element_size(&self) -> usize {
        self.components * self.component.size()
    }
}

/// Vertex attribute with three floats per vertex (POSITION, NORMAL).
pub(super) fn read_vec3(ctx: &Ctx, index: usize, what: &str) -> Result<Vec<Vec3>, LoadError> {
    let format = float_format(ctx, index, Type::Vec3, what)?;
    read_elements(ctx, index, format, Vec3::ZERO, |b| {
        Some(Vec3::new(component(b, 0, format)?, component(b, 1, format)?, component(b, 2, format)?))
    })
}

/// Vertex attribute with two floats per vertex (TEXCOORD_n).
pub(super) fn read_vec2(ctx: &Ctx, index: usize, what: &str) -> Result<Vec<Vec2>, LoadError> {
    let format = float_format(ctx, index, Type::Vec2, what)?;
    read_elements(ctx, index, format, Vec2::ZERO, |b| {
        Some(Vec2::new(component(b, 0, format)?, component(b, 1, format)?))
    })
}

/// Four floats per element (EXT_mesh_gpu_instancing's ROTATION: float, or normalised
/// integers).
pub(super) fn read_vec4(ctx: &Ctx, index: usize, what: &str) -> Result<Vec<Vec4>, LoadError> {
    let format = float_format(ctx, index, Type::Vec4, what)?;
    read_elements(ctx, index, format, Vec4::ZERO, |b| {
        Some(Vec4::new(
            component(b, 0, format)?,
            component(b, 1, format)?,
            component(b, 2, format)?,
            component(b, 3, format)?,
        ))
    })
}

/// Vertex colours (COLOR_n): VEC3 or VEC4 (alpha 1 for VEC3) of float, or of normalised
/// unsigned byte or short, as glTF allows them.
pub(super) fn read_color(ctx: &Ctx, index: usize, what: &str) -> Result<Vec<Vec4>, LoadError> {
    let acc = get(ctx, index)?;
    let rgb = matches!(acc.type_, Checked::Valid(Type::Vec3));
    let format = float_format(ctx, index, if rgb { Type::Vec3 } else { Type::Vec4 }, what)?;
    let allowed = match format.component {
        ComponentType::F32 => true,
        ComponentType::U8 | ComponentType::U16 => format.normalized,
        _ => false,
    };
    if !allowed {
        return Err(ctx.invalid(format!(
            "accessor {index} ({what}) has componentType {}{}; vertex colours must be float or normalized \
             unsigned byte or short",
            format.component.as_gl_enum(),
            if format.normalized { " (normalized)" } else { "" }
        )));
    }
    // Without a bufferView the elements are zeros (alpha 1 for VEC3, which has none).
    let zero = if rgb { Vec4::W } else { Vec4::ZERO };
    read_elements(ctx, index, format, zero, |b| {
        let alpha = if rgb { 1.0 } else { component(b, 3, format)? };
        Some(Vec4::new(component(b, 0, format)?, component(b, 1, format)?, component(b, 2, format)?, alpha))
    })
}

/// Vertex indices (SCALAR of unsigned byte, short or int).
pub(super) fn read_indices(ctx: &Ctx, index: usize, what: &str) -> Result<Vec<u32>, LoadError> {
    let acc = get(ctx, index)?;
    let component = component_type(ctx, index, acc, what)?;
    check_type(ctx, index, acc, Type::Scalar, what)?;
    if !matches!(component, ComponentType::U8 | ComponentType::U16 | ComponentType::U32) {
        return Err(ctx.invalid(format!(
            "accessor {index} ({what}) has componentType {}; indices must be unsigned byte, short or int",
            component.as_gl_enum()
        )));
    }
    let format = Format { component, components: 1, normalized: false };
    read_elements(ctx, index, format, 0, |b| unsigned(b, component))
}

fn get<'r>(ctx: &Ctx<'r>, index: usize) -> Result<&'r json::Accessor, LoadError> {
    ctx.root
        .accessors
        .get(index)
        .ok_or_else(|| ctx.invalid(format!("accessor {index} does not exist ({} accessors)", ctx.root.accessors.len())))
}

fn component_type(ctx: &Ctx, index: usize, acc: &json::Accessor, what: &str) -> Result<ComponentType, LoadError> {
    match acc.component_type {
        Checked::Valid(json::accessor::GenericComponentType(c)) => Ok(c),
        Checked::Invalid => Err(ctx.invalid(format!("accessor {index} ({what}) has an invalid componentType"))),
    }
}

fn check_type(ctx: &Ctx, index: usize, acc: &json::Accessor, expected: Type, what: &str) -> Result<(), LoadError> {
    match acc.type_ {
        Checked::Valid(t) if t == expected => Ok(()),
        Checked::Valid(t) => Err(ctx.invalid(format!(
            "accessor {index} ({what}) has type {}; expected {}",
            type_name(t),
            type_name(expected)
        ))),
        Checked::Invalid => Err(ctx.invalid(format!("accessor {index} ({what}) has an invalid type"))),
    }
}

/// The glTF spelling of an accessor type.
fn type_name(t: Type) -> &'static str {
    match t {
        Type::Scalar => "SCALAR",
        Type::Vec2 => "VEC2",
        Type::Vec3 => "VEC3",
        Type::Vec4 => "VEC4",
        Type::Mat2 => "MAT2",
        Type::Mat3 => "MAT3",
        Type::Mat4 => "MAT4",
    }
}

/// Float attributes: FLOAT, or (KHR_mesh_quantization, and normalised UVs in core glTF)
/// integer components, normalised or not.
fn float_format(ctx: &Ctx, index: usize, expected: Type, what: &str) -> Result<Format, LoadError> {
    let acc = get(ctx, index)?;
    let component = component_type(ctx, index, acc, what)?;
    check_type(ctx, index, acc, expected, what)?;
    if acc.normalized && matches!(component, ComponentType::F32 | ComponentType::U32) {
        return Err(ctx.invalid(format!(
            "accessor {index} ({what}) is normalized with componentType {}, which glTF forbids",
            component.as_gl_enum()
        )));
    }
    Ok(Format { component, components: expected.multiplicity(), normalized: acc.normalized })
}

/// Component `k` of one element, converted to f32 (glTF 2.0 §3.11 for normalised integers).
fn component(element: &[u8], k: usize, f: Format) -> Option<f32> {
    let size = f.component.size();
    let start = k.checked_mul(size)?;
    let b = element.get(start..start.checked_add(size)?)?;
    let n = f.normalized;
    Some(match f.component {
        ComponentType::F32 => f32::from_le_bytes(b.try_into().ok()?),
        ComponentType::U8 => {
            let c = f32::from(*b.first()?);
            if n { c / 255.0 } else { c }
        }
        ComponentType::I8 => {
            let c = f32::from(i8::from_le_bytes(b.try_into().ok()?));
            if n { (c / 127.0).max(-1.0) } else { c }
        }
        ComponentType::U16 => {
            let c = f32::from(u16::from_le_bytes(b.try_into().ok()?));
            if n { c / 65535.0 } else { c }
        }
        ComponentType::I16 => {
            let c = f32::from(i16::from_le_bytes(b.try_into().ok()?));
            if n { (c / 32767.0).max(-1.0) } else { c }
        }
        ComponentType::U32 => u32::from_le_bytes(b.try_into().ok()?) as f32,
    })
}

/// An unsigned integer of the given component type at the start of `b`.
fn unsigned(b: &[u8], component: ComponentType) -> Option<u32> {
    match component {
        ComponentType::U8 => b.first().map(|&c| u32::from(c)),
        ComponentType::U16 => Some(u32::from(u16::from_le_bytes(b.get(..2)?.try_into().ok()?))),
        ComponentType::U32 => Some(u32::from_le_bytes(b.get(..4)?.try_into().ok()?)),
        _ => None,
    }
}

fn to_usize(value: u64) -> Option<usize> {
    usize::try_from(value).ok()
}

/// Reads all `count` elements of accessor `index` (dense part, then sparse substitution).
fn read_elements<T: Copy>(
    ctx: &Ctx,
    index: usize,
    format: Format,
    zero: T,
    decode: impl Fn(&[u8]) -> Option<T>,
) -> Result<Vec<T>, LoadError> {
    let acc = get(ctx, index)?;
    let element = format.element_size();
    let (count, dense) = extent(ctx, index, acc, element)?;
    let mut out = match dense {
        Some((region, stride)) => {
            let oob =
                |detail: String| LoadError::AccessorOutOfBounds { file: ctx.file.into(), accessor: index, detail };
            let mut out = Vec::with_capacity(count);
            for chunk in region.chunks(stride).take(count) {
                let item = chunk.get(..element).and_then(&decode);
                out.push(item.ok_or_else(|| oob("element cut short".into()))?);
            }
            out
        }
        None => vec![zero; count],
    };
    if let Some(sparse) = &acc.sparse {
        apply_sparse(ctx, index, sparse, element, &mut out, &decode)?;
    }
    Ok(out)
}

/// Elements in accessor `index`, checked as [`read_elements`] checks them (against the bytes
/// of its bufferView, or the limit of elements made without one), before anything is read.
pub(super) fn count(ctx: &Ctx, index: usize) -> Result<usize, LoadError> {
    let acc = get(ctx, index)?;
    let component = component_type(ctx, index, acc, "an accessor")?;
    let Checked::Valid(ty) = acc.type_ else {
        return Err(ctx.invalid(format!("accessor {index} has an invalid type")));
    };
    Ok(extent(ctx, index, acc, component.size() * ty.multiplicity())?.0)
}

/// The bytes of an accessor's elements in its bufferView, from its first element to the end
/// of its last, and the stride between elements.
type Dense<'a> = (&'a [u8], usize);

/// The element count of accessor `index` (elements of `element` bytes) and, when a
/// bufferView backs it, the bytes from its first element to the end of its last and the
/// stride: errors where the count overflows, the bytes are not there, or a count without a
/// bufferView exceeds [`MAX_SYNTHETIC_ELEMENTS`].
fn extent<'c>(
    ctx: &'c Ctx,
    index: usize,
    acc: &json::Accessor,
    element: usize,
) -> Result<(usize, Option<Dense<'c>>), LoadError> {
    let oob = |detail: String| LoadError::AccessorOutOfBounds { file: ctx.file.into(), accessor: index, detail };
    let count = to_usize(acc.count.0).ok_or_else(|| oob(format!("count {} is too large", acc.count.0)))?;
    let Some(view) = acc.buffer_view.map(|v| v.value()) else {
        if count > MAX_SYNTHETIC_ELEMENTS {
            return Err(oob(format!(
                "count {count} without a bufferView exceeds livebake's limit of {MAX_SYNTHETIC_ELEMENTS} elements"
            )));
        }
        return Ok((count, None));
    };
    let bytes = ctx.buffers.view(ctx.file, ctx.root, view)?;
    let stride = super::buffers::Buffers::stride(ctx.root, view).unwrap_or(element);
    if stride < element {
        return Err(ctx.invalid(format!(
            "accessor {index}: bufferView {view} has byteStride {stride}, smaller than the {element}-byte element"
        )));
    }
    let offset = acc.byte_offset.map_or(0, |o| o.0);
    if count == 0 {
        return Ok((0, Some((&[], stride))));
    }
    // Last byte read: offset + (count − 1)·stride + element.
    let needed = to_usize(offset)
        .zip((count - 1).checked_mul(stride))
        .and_then(|(o, span)| o.checked_add(span))
        .and_then(|e| e.checked_add(element));
    let needed =
        needed.ok_or_else(|| oob(format!("byteOffset {offset} + count {count} × byteStride {stride} overflows")))?;
    if needed > bytes.len() {
        return Err(oob(format!(
            "count {count} × {element}-byte elements (byteStride {stride}) from byteOffset {offset} needs {needed} bytes but bufferView {view} has {}",
            bytes.len()
        )));
    }
    let start = to_usize(offset).unwrap_or(0);
    let region = bytes.get(start..needed).ok_or_else(|| oob("read outside its bufferView".into()))?;
    Ok((count, Some((region, stride))))
}

fn apply_sparse<T>(
    ctx: &Ctx,
    index: usize,
    sparse: &json::accessor::sparse::Sparse,
    element: usize,
    out: &mut [T],
    decode: &impl Fn(&[u8]) -> Option<T>,
) -> Result<(), LoadError> {
    let oob = |detail: String| LoadError::AccessorOutOfBounds { file: ctx.file.into(), accessor: index, detail };
    let count = to_usize(sparse.count.0)
        .filter(|&c| c <= out.len())
        .ok_or_else(|| oob(format!("sparse count {} exceeds the accessor's count {}", sparse.count.0, out.len())))?;
    let index_type = match sparse.indices.component_type {
        Checked::Valid(json::accessor::IndexComponentType(c)) => c,
        Checked::Invalid => return Err(ctx.invalid(format!("accessor {index}: invalid sparse indices componentType"))),
    };
    let indices = sparse_region(
        ctx,
        index,
        "indices",
        sparse.indices.buffer_view.value(),
        sparse.indices.byte_offset.0,
        count,
        index_type.size(),
    )?;
    let values = sparse_region(
        ctx,
        index,
        "values",
        sparse.values.buffer_view.value(),
        sparse.values.byte_offset.0,
        count,
        element,
    )?;
    let len = out.len();
    for (k, (ib, vb)) in indices.chunks(index_type.size()).zip(values.chunks(element)).enumerate() {
        let target = unsigned(ib, index_type).ok_or_else(|| oob("sparse index cut short".into()))?;
        let value = decode(vb).ok_or_else(|| oob("sparse value cut short".into()))?;
        let slot = out
            .get_mut(target as usize)
            .ok_or_else(|| oob(format!("sparse index {target} (entry {k}) is not below the accessor's count {len}")))?;
        *slot = value;
    }
    Ok(())
}

/// `count` tightly packed items of `size` bytes at `offset` in bufferView `view`.
fn sparse_region<'c>(
    ctx: &'c Ctx,
    index: usize,
    what: &str,
    view: usize,
    offset: u64,
    count: usize,
    size: usize,
) -> Result<&'c [u8], LoadError> {
    let oob = |detail: String| LoadError::AccessorOutOfBounds { file: ctx.file.into(), accessor: index, detail };
    let bytes = ctx.buffers.view(ctx.file, ctx.root, view)?;
    let range = to_usize(offset).and_then(|o| Some((o, o.checked_add(count.checked_mul(size)?)?)));
    range.and_then(|(start, end)| bytes.get(start..end)).ok_or_else(|| {
        oob(format!(
            "sparse {what}: {count} × {size} bytes from byteOffset {offset} do not fit in bufferView {view} ({} bytes)",
            bytes.len()
        ))
    })
}
