//! Warnings gathered while loading: one line per kind of problem with a total count and a few
//! examples, instead of one line per vertex or primitive.

use std::collections::BTreeMap;

/// What was skipped or repaired.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub(super) enum Kind {
    UnsupportedExtensionUsed,
    NonTrianglePrimitive,
    DegenerateTriangles,
    BadNormals,
    BadTexcoord0,
    BadTexcoord1,
    TrailingIndices,
    TexCoordSet,
    TextureWithoutSource,
    TextureUvDiffers,
    UnnormalizedRotation,
    IgnoredSkin,
    IgnoredMorphTargets,
    EmptyMesh,
    LightSkipped,
    LightParameter,
    CameraSkipped,
    BaseColorClamped,
}

impl Kind {
    /// `count` is what the tally counts (vertices, triangles, primitives...).
    fn describe(self, count: usize) -> String {
        match self {
            Kind::UnsupportedExtensionUsed => {
                format!("{count} extension(s) used by the file are not supported and were ignored")
            }
            Kind::NonTrianglePrimitive => {
                format!("{count} point/line primitive(s) skipped (only triangles are light-mapped)")
            }
            Kind::DegenerateTriangles => format!("{count} zero-area triangle(s) dropped"),
            Kind::BadNormals => {
                format!("{count} vertex normal(s) were zero or not finite and were replaced by face normals")
            }
            Kind::BadTexcoord0 => format!("{count} non-finite TEXCOORD_0 value(s) replaced by (0, 0)"),
            Kind::BadTexcoord1 => format!(
                "{count} primitive(s) have non-finite TEXCOORD_1 values: their TEXCOORD_1 is ignored (light-map UVs will be generated)"
            ),
            Kind::TrailingIndices => {
                format!("{count} trailing index/vertex value(s) that do not make a whole triangle were ignored")
            }
            Kind::TexCoordSet => format!(
                "{count} material texture(s) use a texCoord above 1; livebake reads those textures at TEXCOORD_0"
            ),
            Kind::TextureUvDiffers => format!(
                "{count} material texture(s) are read at other coordinates (texCoord or KHR_texture_transform) than their material's base colour texture; livebake reads them at the base colour's"
            ),
            Kind::UnnormalizedRotation => {
                format!("{count} node rotation(s) were not unit quaternions and were normalised")
            }
            Kind::IgnoredSkin => {
                format!("{count} skinned mesh instance(s): skinning is ignored (meshes placed by their node transform)")
            }
            Kind::IgnoredMorphTargets => {
                format!("{count} primitive(s) have morph targets, which are ignored (base shape used)")
            }
            Kind::TextureWithoutSource => format!(
                "{count} texture(s) have no image livebake decodes (only an extension's: KTX2, WebP or DDS): their materials show their factors alone"
            ),
            Kind::EmptyMesh => format!("{count} primitive instance(s) had no triangles left and were left out"),
            Kind::LightSkipped => format!("{count} light(s) skipped"),
            Kind::LightParameter => format!("{count} light parameter(s) out of range were corrected"),
            Kind::CameraSkipped => format!("{count} camera(s) skipped"),
            Kind::BaseColorClamped => {
                format!("{count} base colour factor(s) outside [0, 1] clamped (an albedo above 1 would make light)")
            }
        }
    }
}

#[derive(Default)]
struct Tally {
    count: usize,
    places: usize,
    examples: Vec<String>,
}

/// Collects warnings during a load; [`Diagnostics::finish`] turns them into messages.
#[derive(Default)]
pub(super) struct Diagnostics {
    tallies: BTreeMap<Kind, Tally>,
}

const MAX_EXAMPLES: usize = 3;

impl Diagnostics {
    /// Records `count` occurrences of `kind` at `place` (a mesh instance, material, node...).
    pub(super) fn note(&mut self, kind: Kind, count: usize, place: impl FnOnce() -> String) {
        if count == 0 {
            return;
        }
        let t = self.tallies.entry(kind).or_default();
        t.count += count;
        t.places += 1;
        if t.examples.len() < MAX_EXAMPLES {
            t.examples.push(place());
        }
    }

    /// Total recorded for `kind`.
    pub(super) fn count(&self, kind: Kind) -> usize {
        self.tallies.get(&kind).map_or(0, |t| t.count)
    }

    /// One message per kind, e.g. `12 zero-area triangle(s) dropped (in 2 places, e.g. a/b/0; c/d/1)`.
    pub(super) fn finish(self) -> Vec<String> {
        self.tallies
            .into_iter()
            .map(|(kind, t)| {
                let more = if t.places > t.examples.len() { "; ..." } else { "" };
                format!("{} (in {} place(s): {}{more})", kind.describe(t.count), t.places, t.examples.join("; "))
            })
            .collect()
    }
}
