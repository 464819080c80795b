//! Filters over a light map's texels that never cross a chart border: a texel's neighbours
//! are the texels of its own chart around its pixel (never a gutter pixel, which copies a
//! texel, nor another chart's pixel).

use super::lookup::TexelTable;
use super::texels::NO_TEXEL;
use crate::scene::Rgb;

/// The 3×3 tent (1-2-1 per axis) weight of neighbour (dx, dy), and which neighbours of a
/// texel count: texels of the same chart and set, never a gutter pixel nor another chart's
/// pixel. Calls `each(j, w)` for texel `i`'s neighbours (itself included).
fn for_each_neighbour<'t>(
    pixels: &[[u32; 2]],
    table: &impl Fn(usize) -> &'t TexelTable,
    i: usize,
    mut each: impl FnMut(usize, f32),
) {
    let [x, y] = pixels[i];
    let chart = table(i);
    for dy in -1i64..=1 {
        for dx in -1i64..=1 {
            let (nx, ny) = (x as i64 + dx, y as i64 + dy);
            let j = chart.get(nx, ny);
            if j == NO_TEXEL || pixels.get(j as usize) != Some(&[nx as u32, ny as u32]) {
                continue;
            }
            each(j as usize, ((2 - dx.abs()) * (2 - dy.abs())) as f32);
        }
    }
}

/// A 3×3 tent filter over each texel and its neighbours of the same chart, never across a
/// chart border: bundles of parallel lines leave streaks along the last directions' lines,
/// which this smooths at the scale of one texel. `pixels[i]` is texel i's LOD pixel and
/// `table(i)` the lookup table of its chart. Texels with no estimate (`sampled(i)` false: no
/// bundle line reached them, as for a texel wholly inside closed geometry) are left out of
/// their neighbours' means and take the mean of their sampled neighbours, so bilinear
/// sampling at a visible texel beside them never reads their zero; one with no sampled
/// neighbour keeps its value.
pub fn filter_within_charts<'t>(
    pixels: &[[u32; 2]],
    table: impl Fn(usize) -> &'t TexelTable,
    values: &[Rgb],
    sampled: impl Fn(usize) -> bool,
) -> Vec<Rgb> {
    (0..pixels.len())
        .map(|i| {
            let (mut sum, mut wsum) = (Rgb::ZERO, 0.0);
            for_each_neighbour(pixels, &table, i, |j, w| {
                if sampled(j) {
                    sum += values[j] * w;
                    wsum += w;
                }
            });
            if wsum > 0.0 { sum / wsum } else { values[i] }
        })
        .collect()
}

/// [`filter_within_charts`] of one value per texel, NaN marking texels without one (they
/// are left out, and stay NaN when no neighbour has a value).
pub fn filter_scalar_within_charts<'t>(
    pixels: &[[u32; 2]],
    table: impl Fn(usize) -> &'t TexelTable,
    values: &[f32],
) -> Vec<f32> {
    (0..pixels.len())
        .map(|i| {
            let (mut sum, mut wsum) = (0.0, 0.0);
            for_each_neighbour(pixels, &table, i, |j, w| {
                if !values[j].is_nan() {
                    sum += values[j] * w;
                    wsum += w;
                }
            });
            if wsum > 0.0 { sum / wsum } else { f32::NAN }
        })
        .collect()
}
