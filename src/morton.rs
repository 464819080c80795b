//! Z-order (Morton) keys of points in a 3D grid: sorting by them keeps neighbours in space
//! near each other in the order (the punctual pass's texel walk, region shards' charts).

/// The Z-order key of grid cell `(x, y, z)`, 21 bits an axis: bit i of x, y and z lands on
/// bits 3i, 3i + 1 and 3i + 2 of the key. Higher bits of the coordinates are ignored.
pub fn key3(x: u32, y: u32, z: u32) -> u64 {
    spread_bits(x) | spread_bits(y) << 1 | spread_bits(z) << 2
}

/// Spreads the low 21 bits of `v` to every third bit of a u64.
fn spread_bits(v: u32) -> u64 {
    let mut v = v as u64 & 0x1f_ffff;
    v = (v | v << 32) & 0x1f_0000_0000_ffff;
    v = (v | v << 16) & 0x1f_0000_ff00_00ff;
    v = (v | v << 8) & 0x100f_00f0_0f00_f00f;
    v = (v | v << 4) & 0x10c3_0c30_c30c_30c3;
    (v | v << 2) & 0x1249_2492_4924_9249
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The axes interleave: bit i of an axis lands on bit 3i (+ the axis).
    #[test]
    fn keys_interleave_the_axes() {
        for i in 0..21 {
            assert_eq!(key3(1 << i, 0, 0), 1u64 << (3 * i));
            assert_eq!(key3(0, 1 << i, 0), 1u64 << (3 * i + 1));
            assert_eq!(key3(0, 0, 1 << i), 1u64 << (3 * i + 2));
        }
        assert_eq!(key3(u32::MAX, u32::MAX, u32::MAX), u64::MAX >> 1);
    }
}
