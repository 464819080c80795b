//! Filters over a light map's texels that never cross a chart border: a texel's neighbours
//! are the texels of its own chart around its pixel (never a gutter pixel, which copies a
//! texel, nor another chart's pixel).

use super::lookup::TexelTable;
use super::texels::NO_TEXEL;
use crate::scene::Rgb;

/// The 3×3 tent (1-2-1 per axis) weight of neighbour (dx, dy), and which neighbours of a
/// texel count: texels of the same chart and set, never a gutter pixel nor another chart's
/// pixel. Calls `each(j, w)` for texel `i`'s neighbours (itself included).
pub(crate) fn for_each_neighbour<'t>(
    pixel: &impl Fn(usize) -> [u32; 2],
    table: &impl Fn(usize) -> &'t TexelTable,
    i: usize,
    mut each: impl FnMut(usize, f32),
) {
    let [x, y] = pixel(i);
    let chart = table(i);
    for dy in -1i64..=1 {
        for dx in -1i64..=1 {
            let (nx, ny) = (x as i64 + dx, y as i64 + dy);
            let j = chart.get(nx, ny);
            if j == NO_TEXEL || pixel(j as usize) != [nx as u32, ny as u32] {
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
            for_each_neighbour(&|k| pixels[k], &table, i, |j, w| {
                if sampled(j) {
                    sum += values[j] * w;
                    wsum += w;
                }
            });
            if wsum > 0.0 { sum / wsum } else { values[i] }
        })
        .collect()
}

/// Gives each texel of `missing` (ascending) the tent-weighted mean of its chart neighbours
/// not in it (one without such neighbours keeps its value): texels with no value of their
/// own, wholly inside closed geometry, that bilinear sampling at a visible texel beside them
/// still reads.
pub fn fill_within_charts<'t>(
    pixel: impl Fn(usize) -> [u32; 2],
    table: impl Fn(usize) -> &'t TexelTable,
    values: &mut [Rgb],
    missing: &[u32],
) {
    let has = |j: usize| missing.binary_search(&(j as u32)).is_err();
    let filled: Vec<Rgb> = missing
        .iter()
        .map(|&i| {
            let (mut sum, mut wsum) = (Rgb::ZERO, 0.0);
            for_each_neighbour(&pixel, &table, i as usize, |j, w| {
                if has(j) {
                    sum += values[j] * w;
                    wsum += w;
                }
            });
            if wsum > 0.0 { sum / wsum } else { values[i as usize] }
        })
        .collect();
    for (&i, v) in missing.iter().zip(filled) {
        values[i as usize] = v;
    }
}

/// [`filter_within_charts`] of one value per texel, NaN marking texels without one (they
/// are left out, and stay NaN when no neighbour has a value).
pub fn filter_scalar_within_charts<'t>(
    pixels: &[[u32; 2]],
    table: impl Fn(usize) -> &'t TexelTable,
    values: &[f32],
) -> Vec<f32> {
    (0..pixels.len())
        .map(|i| neighbour_mean(pixels, &table, values, i, |j| !values[j].is_nan()).unwrap_or(f32::NAN))
        .collect()
}

/// The tent-weighted mean of `values` over texel `i`'s chart neighbours `j` for which
/// `counts(j)`; `None` when none counts.
fn neighbour_mean<'t>(
    pixels: &[[u32; 2]],
    table: &impl Fn(usize) -> &'t TexelTable,
    values: &[f32],
    i: usize,
    counts: impl Fn(usize) -> bool,
) -> Option<f32> {
    let (mut sum, mut wsum) = (0.0, 0.0);
    for_each_neighbour(&|k| pixels[k], table, i, |j, w| {
        if counts(j) {
            sum += values[j] * w;
            wsum += w;
        }
    });
    (wsum > 0.0).then(|| sum / wsum)
}

/// Per texel: the squared difference between `values[i]` and the tent-weighted mean of its
/// chart neighbours (itself left out); NaN for a texel with none. What a finer level of the
/// same light would resolve shows here first: light that changes from texel to texel.
pub fn contrast_within_charts<'t>(
    pixels: &[[u32; 2]],
    table: impl Fn(usize) -> &'t TexelTable,
    values: &[f32],
) -> Vec<f32> {
    (0..pixels.len())
        .map(|i| neighbour_mean(pixels, &table, values, i, |j| j != i).map_or(f32::NAN, |m| (values[i] - m).powi(2)))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 3×2 chart: texel 5 has no sampled value; the filter leaves it out of its
    /// neighbours and gives it their mean; contrast is each texel against its neighbours.
    #[test]
    fn filters_skip_unsampled_texels_and_contrast_leaves_the_texel_out() {
        let pixels: Vec<[u32; 2]> = vec![[0, 0], [1, 0], [2, 0], [0, 1], [1, 1], [2, 1]];
        let mut table = TexelTable::new(Some(0), crate::atlas::raster::PixelRect::new(0, 0, 3, 2));
        for (i, p) in pixels.iter().enumerate() {
            table.set(p[0] as i64, p[1] as i64, i as u32);
        }
        let values: Vec<Rgb> = [1.0, 1.0, 1.0, 1.0, 1.0, 0.0].iter().map(|&v| Rgb::splat(v)).collect();
        let f = filter_within_charts(&pixels, |_| &table, &values, |i| i != 5);
        assert!(f.iter().all(|v| (*v - Rgb::ONE).length() < 1e-6), "{f:?}");
        let g = filter_within_charts(&pixels, |_| &table, &values, |_| true);
        assert!(g[4].x < 1.0, "an unsampled zero counts when it is taken as sampled");
        let c = contrast_within_charts(&pixels, |_| &table, &[0.0, 0.0, 0.0, 0.0, 0.0, 4.0]);
        assert_eq!(c[0], 0.0);
        // Texel 5's neighbours (2 with weight 2, 1 with 1, 4 with 2) are all 0: (4 − 0)².
        assert_eq!(c[5], 16.0);
        assert!(c[4] > 0.0);
    }
}
