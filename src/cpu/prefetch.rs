//! Software prefetches of per-texel values ahead of their use. Large LODs' sums and sources
//! outgrow every cache (23.8 M texels hold 0.4 GB of sums), and the resolve reaches them in
//! an order no hardware prefetcher follows; where the texels are known a little ahead (a
//! row's fill before its exchange, a unit's records before they are added), asking for
//! their lines then hides part of the wait.

use crate::bundle::estimator::TexelLayout;

/// What a tile's resolve prefetches for a texel when its fill first meets it: the texel's
/// source (what its neighbours along a line see of it) and its sums (where its hits go).
/// The fill of a row runs a row's fragments ahead of their exchange.
pub(super) fn prefetcher(source: TexelLayout, sums: TexelLayout) -> impl Fn(u32) {
    move |t| {
        for layout in [source, sums] {
            if let Some(at) = layout.address(t) {
                prefetch(at);
            }
        }
    }
}

/// Asks the cache for the line at address `at` ahead of its use: a hint, nothing is read.
#[inline(always)]
fn prefetch(at: usize) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: a prefetch reads no memory and cannot fault, whatever the address.
    unsafe {
        std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(at as *const i8)
    };
    #[cfg(not(target_arch = "x86_64"))]
    let _ = at;
}

/// How many records ahead [`for_each_ahead`] asks for a texel's sums: about a DRAM latency's
/// worth of adding records.
const RECORDS_AHEAD: usize = 16;

/// Calls `f` on each of `items` in order, having asked for the sums (`layout`) of the texel
/// of the item [`RECORDS_AHEAD`] further on.
#[inline]
pub(super) fn for_each_ahead<T>(items: &[T], layout: TexelLayout, texel: impl Fn(&T) -> u32, mut f: impl FnMut(&T)) {
    for (i, item) in items.iter().enumerate() {
        if let Some(at) = items.get(i + RECORDS_AHEAD).and_then(|a| layout.address(texel(a))) {
            prefetch(at);
        }
        f(item);
    }
}
