use super::*;
use crate::sampling::Rng;

fn maps(side: u32, importance: Vec<f32>, fragments: Vec<f32>) -> (MipChain, MipChain) {
    (MipChain::max_mips(side, importance).unwrap(), MipChain::average_mips(side, fragments).unwrap())
}

fn plan(maps: &(MipChain, MipChain), params: TileParams, mode: TilingMode) -> TilePlan {
    plan_tiles(&maps.0, &maps.1, params, mode).unwrap()
}

fn tile(level: i32, x: u32, y: u32, res: u32) -> Tile {
    Tile { level, x, y, res }
}

/// α = 1 keeps the hand-computed budgets round.
fn params(w: u32, n: u64, pixel_area: f64) -> TileParams {
    TileParams { alpha: 1.0, ..TileParams::new(w, n, pixel_area) }
}

#[test]
fn importance_beyond_the_head_buffer_splits() {
    // 2×2, A(0) = 1, A(1) = 4, W² = 4, memory unbounded (F = 1, N huge).
    // Top: C_I = 4·4 = 16 > 4 → split. Children: C_I = 4, 1, 0, 0.25.
    let m = maps(2, vec![4.0, 1.0, 0.0, 0.25], vec![1.0; 4]);
    let p = plan(&m, params(2, 1 << 40, 1.0), TilingMode::Adaptive);
    assert_eq!(p.tiles, [tile(0, 0, 0, 2), tile(0, 1, 0, 1), tile(0, 1, 1, 1)]);
    let expected = PlanStats { tiles: 3, splits_for_importance: 1, ..Default::default() };
    assert_eq!(p.stats, expected);
}

#[test]
fn a_tile_exactly_at_its_bound_is_emitted() {
    // C_I = 4·1 = 4 = W²: Eq. 3 splits only when C_I > C_max (Program 1's `CI < Cmax`
    // emit test would split here).
    let m = maps(2, vec![1.0; 4], vec![1.0; 4]);
    let p = plan(&m, params(2, 1 << 20, 1.0), TilingMode::Adaptive);
    assert_eq!(p.tiles, [tile(1, 0, 0, 2)]);
    assert_eq!(p.stats, PlanStats { tiles: 1, ..Default::default() });
}

#[test]
fn a_split_with_both_bounds_equal_counts_for_importance() {
    // W² = 9 and αN/F = 90/10 = 9: memory is not *below* the head buffer, so the head
    // buffer is the binding bound.
    let m = maps(2, vec![3.0; 4], vec![10.0; 4]);
    let p = plan(&m, params(3, 90, 1.0), TilingMode::Adaptive);
    assert_eq!(p.stats.splits_for_importance, 1);
    assert_eq!(p.stats.splits_for_memory, 0);
}

#[test]
fn predicted_overflow_splits() {
    // F = 10 everywhere, αN = 90: C_max = 9 (W² = 4096 is far). Top: C_I = 4·3 = 12 > 9.
    let m = maps(2, vec![3.0; 4], vec![10.0; 4]);
    let p = plan(&m, params(64, 90, 1.0), TilingMode::Adaptive);
    assert_eq!(p.tiles, [tile(0, 0, 0, 2), tile(0, 1, 0, 2), tile(0, 0, 1, 2), tile(0, 1, 1, 2)]);
    let expected = PlanStats { tiles: 4, splits_for_memory: 1, ..Default::default() };
    assert_eq!(p.stats, expected);
    // The same importance fits when fragments are fewer: one tile, ⌈√12⌉ = 4 wide.
    let sparse = maps(2, vec![3.0; 4], vec![5.0; 4]);
    let p = plan(&sparse, params(64, 90, 1.0), TilingMode::Adaptive);
    assert_eq!(p.tiles, [tile(1, 0, 0, 4)]);
    assert_eq!(p.stats.splits_for_memory, 0);
}

#[test]
fn a_coarse_fragment_estimate_can_bind_a_finer_tile() {
    // 4×4: the top-left 2×2 block has F = 1, the rest F = 100, so F(1) = [1, 100, 100, 100]
    // and F(2) = 75.25. αN = 900. Importance 4 in the top-left block only.
    let mut importance = vec![0.0; 16];
    let mut fragments = vec![100.0; 16];
    for (x, y) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
        importance[y * 4 + x] = 4.0;
        fragments[y * 4 + x] = 1.0;
    }
    let m = maps(4, importance, fragments);
    let params = params(64, 900, 1.0);
    let planner = TilePlanner::new(&m.0, &m.1, params).unwrap();
    // Tile (1, 0, 0) needs 4·4 = 16 rays. Its own F allows 900 (Eq. 2 would emit it), but
    // its parent's average allows 900 / 75.25 ≈ 11.96: Eq. 3 splits it.
    assert_eq!(planner.rays_needed(1, 0, 0), 16.0);
    assert_eq!(900.0 / m.1.get(1, 0, 0) as f64, 900.0);
    assert_eq!(planner.ray_bound(1, 0, 0), 900.0 / 75.25);
    let p = planner.plan(TilingMode::Adaptive).unwrap();
    assert_eq!(p.tiles, [tile(0, 0, 0, 2), tile(0, 1, 0, 2), tile(0, 0, 1, 2), tile(0, 1, 1, 2)]);
    let expected = PlanStats { tiles: 4, splits_for_memory: 2, ..Default::default() };
    assert_eq!(p.stats, expected);
}

#[test]
fn finest_tiles_are_emitted_undersampled_when_over_the_bound() {
    // 1×1 map: level 0 is the top and cannot split.
    // Head-buffer bound: C_I = 100 > W² = 16 → 4×4, undersampled.
    let m = maps(1, vec![100.0], vec![1.0]);
    let p = plan(&m, params(4, 1 << 30, 1.0), TilingMode::Adaptive);
    assert_eq!(p.tiles, [tile(0, 0, 0, 4)]);
    let expected = PlanStats { tiles: 1, undersampled_tiles: 1, ..Default::default() };
    assert_eq!(p.stats, expected);
    // Memory bound: F = 50, αN = 90 → C_max = 1.8 → a single pixel.
    let m = maps(1, vec![100.0], vec![50.0]);
    let p = plan(&m, params(64, 90, 1.0), TilingMode::Adaptive);
    assert_eq!(p.tiles, [tile(0, 0, 0, 1)]);
    assert_eq!(p.stats.undersampled_tiles, 1);
}

#[test]
fn rounding_up_never_breaks_the_memory_bound() {
    // C_I = 10 ≤ C_max = 10.5: ⌈√10⌉ = 4 would put 16 pixels·F = 16 nodes in a 10.5
    // budget; the planner takes ⌊√10.5⌋ = 3.
    let m = maps(1, vec![10.0], vec![1.0]);
    let p = plan(&m, TileParams { alpha: 0.5, ..TileParams::new(64, 21, 1.0) }, TilingMode::Adaptive);
    assert_eq!(p.tiles, [tile(0, 0, 0, 3)]);
    assert_eq!(p.stats.undersampled_tiles, 0);
    assert_eq!(bundle_resolution(10.0, 10.5), 3);
    assert_eq!(bundle_resolution(10.0, 16.0), 4);
    assert_eq!(bundle_resolution(16.0, 16.0), 4);
    assert_eq!(bundle_resolution(0.01, 16.0), 1);
    assert_eq!(bundle_resolution(5.0, 0.5), 1);
}

#[test]
fn zero_importance_is_never_planned() {
    let zeros = maps(4, vec![0.0; 16], vec![3.0; 16]);
    for mode in [TilingMode::None, TilingMode::Uniform { k: 2 }, TilingMode::Adaptive] {
        assert_eq!(plan(&zeros, params(8, 100, 1.0), mode), TilePlan::default(), "{mode:?}");
    }
    // One lit pixel in a corner: after the splits only its branch is emitted.
    let mut importance = vec![0.0; 16];
    importance[15] = 1.0;
    let m = maps(4, importance, vec![1.0; 16]);
    let p = plan(&m, params(1, 1 << 20, 1.0), TilingMode::Adaptive);
    assert_eq!(p.tiles, [tile(0, 3, 3, 1)]);
    assert_eq!(p.stats.splits_for_importance, 2);
}

#[test]
fn no_tiling_is_one_window_wide_tile() {
    let m = maps(8, vec![1.0; 64], vec![1.0; 64]);
    let p = plan(&m, params(256, 1, 1.0), TilingMode::None);
    assert_eq!(p.tiles, [tile(3, 0, 0, 256)]);
    assert_eq!(p.stats, PlanStats { tiles: 1, ..Default::default() });
}

#[test]
fn uniform_tiling_is_k_by_k_tiles_at_full_resolution() {
    // 8×8 with importance everywhere but the top-right quarter.
    let importance: Vec<f32> = (0..64).map(|i| if i % 8 >= 4 && i / 8 < 4 { 0.0 } else { 1.0 }).collect();
    let m = maps(8, importance, vec![1.0; 64]);
    let p = plan(&m, params(32, 1, 1.0), TilingMode::Uniform { k: 2 });
    assert_eq!(p.tiles, [tile(2, 0, 0, 32), tile(2, 0, 1, 32), tile(2, 1, 1, 32)]);
    let p = plan(&m, params(32, 1, 1.0), TilingMode::Uniform { k: 8 });
    assert_eq!(p.tiles.len(), 48);
    assert!(p.tiles.iter().all(|t| t.level == 0 && t.res == 32));
    let whole = plan(&m, params(32, 1, 1.0), TilingMode::Uniform { k: 1 });
    assert_eq!(whole, plan(&m, params(32, 1, 1.0), TilingMode::None));
}

#[test]
fn uniform_tiling_rejects_bad_tile_counts() {
    let m = maps(8, vec![1.0; 64], vec![1.0; 64]);
    for k in [0, 3, 6, 16] {
        assert_eq!(
            plan_tiles(&m.0, &m.1, params(32, 1, 1.0), TilingMode::Uniform { k }),
            Err(PlanError::InvalidUniformTiling { k, side: 8 })
        );
    }
}

#[test]
fn planner_rejects_inconsistent_inputs() {
    let m = maps(4, vec![1.0; 16], vec![1.0; 16]);
    let small = maps(2, vec![1.0; 4], vec![1.0; 4]);
    let ok = params(8, 100, 1.0);
    let new = |i: &MipChain, f: &MipChain, p: TileParams| TilePlanner::new(i, f, p).map(|_| ());
    assert_eq!(new(&m.0, &small.1, ok), Err(PlanError::MapSizeMismatch { importance: 4, fragments: 2 }));
    assert_eq!(new(&m.1, &m.0, ok), Err(PlanError::WrongReduction));
    assert_eq!(new(&m.0, &m.1, TileParams { w: 0, ..ok }), Err(PlanError::EmptyHeadBuffer));
    assert_eq!(new(&m.0, &m.1, TileParams { n: 0, ..ok }), Err(PlanError::EmptyNodeBuffer));
    for alpha in [0.0, -0.5, 1.5, f32::NAN] {
        assert!(matches!(new(&m.0, &m.1, TileParams { alpha, ..ok }), Err(PlanError::AlphaOutOfRange(_))));
    }
    for pixel_area in [0.0, -1.0, f64::INFINITY, f64::NAN] {
        assert!(matches!(new(&m.0, &m.1, TileParams { pixel_area, ..ok }), Err(PlanError::InvalidPixelArea(_))));
    }
    assert_eq!(new(&m.0, &m.1, ok), Ok(()));
}

#[test]
fn tile_helpers() {
    let m = maps(8, vec![1.0; 64], (0..64).map(|i| (i % 5) as f32).collect());
    let params = params(64, 1000, 0.25);
    let planner = TilePlanner::new(&m.0, &m.1, params).unwrap();
    let t = tile(2, 1, 0, 8);
    assert_eq!(t.window(), TileWindow { x: 4.0, y: 0.0, side: 4.0 });
    assert_eq!(params.tile_area(2), 4.0);
    assert_eq!(t.bundle_pixel_area(&params), 4.0 / 64.0);
    assert_eq!(planner.predicted_nodes(&t), 64.0 * m.1.get(2, 1, 0) as f64);
    assert_eq!(params.head_buffer_pixels(), 4096.0);
    assert_eq!(params.node_budget(), 1000.0);
    assert_eq!(TileParams::new(1, 1, 1.0).alpha, DEFAULT_ALPHA);
}

#[test]
fn tiles_come_in_morton_order() {
    let m = maps(4, vec![1.0; 16], vec![1.0; 16]);
    let p = plan(&m, params(1, 1 << 20, 1.0), TilingMode::Uniform { k: 4 });
    let order: Vec<(u32, u32)> = p.tiles.iter().map(|t| (t.x, t.y)).collect();
    let z_curve = [(0, 0), (1, 0), (0, 1), (1, 1), (2, 0), (3, 0), (2, 1), (3, 1)];
    assert_eq!(order[..8], z_curve);
    assert_eq!(order[8..10], [(0, 2), (1, 2)]);
}

// ---- Property tests on random maps -------------------------------------------------------

/// A random analysis of side 2^k: importance spanning six decades, with a random share of
/// zero pixels (none, half, nearly all) either scattered or in blocks; depth complexity
/// mostly small with a few deep pixels and some empty ones.
fn random_maps(rng: &mut Rng) -> (MipChain, MipChain) {
    let side = 1u32 << (rng.next_u32() % 7);
    let zero_share = [0.0, 0.5, 0.9, 0.99][rng.next_u32() as usize % 4];
    let block = 1u32 << (rng.next_u32() % 3).min(side.trailing_zeros());
    let blocks_per_row = side / block;
    let zero_blocks: Vec<bool> = (0..blocks_per_row * blocks_per_row).map(|_| rng.next_f32() < zero_share).collect();
    let mut importance = Vec::with_capacity((side * side) as usize);
    let mut fragments = Vec::with_capacity((side * side) as usize);
    for y in 0..side {
        for x in 0..side {
            let zero = zero_blocks[((y / block) * blocks_per_row + x / block) as usize];
            importance.push(if zero { 0.0 } else { 10f32.powf(rng.next_f32() * 6.0 - 3.0) });
            fragments.push(match rng.next_u32() % 10 {
                0 => 0.0,
                1 => (rng.next_u32() % 2000) as f32,
                _ => (1 + rng.next_u32() % 20) as f32,
            });
        }
    }
    maps(side, importance, fragments)
}

/// Buffer sizes and scale around the maps' own: the whole window needs from 1/100 to 10⁴
/// head buffers of rays, and the node buffer holds from 1/1000 to 10 head buffers at the
/// mean depth complexity, so tiles end at every level and either bound may bind.
fn random_params(rng: &mut Rng, maps: &(MipChain, MipChain)) -> TileParams {
    let w = [1u32, 3, 16, 64, 1024][rng.next_u32() as usize % 5];
    let head = w as f64 * w as f64;
    let top = maps.0.top_level();
    let max_importance = (maps.0.get(top, 0, 0) as f64).max(1e-3);
    let window_rays = head * 10f64.powf(rng.next_f32() as f64 * 6.0 - 2.0);
    let mean_depth = (maps.1.get(top, 0, 0) as f64).max(1.0);
    let nodes = head * mean_depth * 10f64.powf(rng.next_f32() as f64 * 4.0 - 3.0);
    TileParams {
        w,
        n: nodes.max(1.0) as u64,
        alpha: if rng.next_f32() < 0.5 { DEFAULT_ALPHA } else { 0.05 + 0.95 * rng.next_f32() },
        pixel_area: window_rays / (4f64.powi(top as i32) * max_importance),
    }
}

fn random_modes(rng: &mut Rng, side: u32) -> [TilingMode; 3] {
    let k = 1 << (rng.next_u32() % (side.trailing_zeros() + 1));
    [TilingMode::None, TilingMode::Uniform { k }, TilingMode::Adaptive]
}

/// How many tiles cover each finest pixel.
fn coverage(tiles: &[Tile], side: u32) -> Vec<u32> {
    let mut count = vec![0u32; (side * side) as usize];
    for t in tiles {
        let w = t.window();
        let (x0, y0, s) = (w.x as u32, w.y as u32, w.side as u32);
        for y in y0..y0 + s {
            for x in x0..x0 + s {
                count[(y * side + x) as usize] += 1;
            }
        }
    }
    count
}

const CASES: u64 = 400;

#[test]
fn every_lit_pixel_is_covered_exactly_once_and_no_tile_is_dark() {
    let mut rng = Rng::new(1, 1);
    for case in 0..CASES {
        let m = random_maps(&mut rng);
        let params = random_params(&mut rng, &m);
        let side = m.0.side();
        for mode in random_modes(&mut rng, side) {
            let p = plan(&m, params, mode);
            let covered = coverage(&p.tiles, side);
            for (i, (&count, &importance)) in covered.iter().zip(m.0.level(0)).enumerate() {
                let expected = if importance > 0.0 { 1 } else { count.min(1) };
                assert_eq!(count, expected, "case {case} {mode:?}: pixel {i} covered {count} times");
            }
            for t in &p.tiles {
                let level = t.level as u32;
                assert!(m.0.get(level, t.x, t.y) > 0.0, "case {case} {mode:?}: dark tile {t:?}");
                assert!(t.res >= 1 && t.res <= params.w, "case {case} {mode:?}: {t:?}");
            }
            assert_eq!(p.stats.tiles, p.tiles.len());
            let keys: Vec<u64> = p.tiles.iter().map(Tile::morton_key).collect();
            assert!(keys.windows(2).all(|k| k[0] < k[1]), "case {case} {mode:?}: not in Z-order");
        }
    }
}

/// Largest F(j, x_j) over the tile and its ancestors, walked independently of the planner.
fn deepest_estimate(fragments: &MipChain, t: &Tile) -> f64 {
    let level = t.level as u32;
    (level..=fragments.top_level())
        .map(|j| fragments.get(j, t.x >> (j - level), t.y >> (j - level)) as f64)
        .fold(0.0, f64::max)
}

/// What Eq. 3 guarantees, per emitted tile: res ≤ W and res²·F(j, x_j) ≤ αN for the tile
/// and every ancestor j, i.e. res² ≤ αN / max_j F(j, x_j) (a single pixel is allowed where
/// even one exceeds the budget). And what Eq. 1 asks: res² ≥ C_I, except for the
/// undersampled finest tiles and the rounding cap of `bundle_resolution`.
#[test]
fn adaptive_tiles_keep_what_eq_3_promises() {
    let mut rng = Rng::new(2, 2);
    for case in 0..CASES {
        let m = random_maps(&mut rng);
        let params = random_params(&mut rng, &m);
        let planner = TilePlanner::new(&m.0, &m.1, params).unwrap();
        let p = planner.plan(TilingMode::Adaptive).unwrap();
        let mut undersampled = 0;
        for t in &p.tiles {
            let level = t.level as u32;
            let res2 = t.res as f64 * t.res as f64;
            let fits_one_pixel = deepest_estimate(&m.1, t) <= params.node_budget();
            let memory_ok = res2 * deepest_estimate(&m.1, t) <= params.node_budget() * (1.0 + 1e-12);
            assert!(t.res <= params.w, "case {case}: {t:?} wider than W");
            assert!(memory_ok || (t.res == 1 && !fits_one_pixel), "case {case}: {t:?} overflows");
            let rays = planner.rays_needed(level, t.x, t.y);
            let bound = planner.ray_bound(level, t.x, t.y);
            if rays > bound {
                assert_eq!(level, 0, "case {case}: {t:?} over its bound above level 0");
                undersampled += 1;
            } else {
                let rounded_down = (t.res as f64 + 1.0).powi(2) > bound;
                assert!(res2 >= rays || rounded_down, "case {case}: {t:?} undersamples");
            }
            assert_eq!(planner.predicted_nodes(t), res2 * m.1.get(level, t.x, t.y) as f64);
        }
        assert_eq!(p.stats.undersampled_tiles, undersampled, "case {case}");
    }
}

/// Tiles are only as small as they must be: every emitted tile's parent needed splitting,
/// and the number of splits matches the tree (each split makes four children, emitted,
/// dark or split again).
#[test]
fn adaptive_tiles_are_no_smaller_than_needed() {
    let mut rng = Rng::new(3, 3);
    for case in 0..CASES {
        let m = random_maps(&mut rng);
        let planner = TilePlanner::new(&m.0, &m.1, random_params(&mut rng, &m)).unwrap();
        let p = planner.plan(TilingMode::Adaptive).unwrap();
        for t in p.tiles.iter().filter(|t| t.level < m.0.top_level() as i32) {
            let (level, x, y) = (t.level as u32 + 1, t.x / 2, t.y / 2);
            assert!(
                planner.rays_needed(level, x, y) > planner.ray_bound(level, x, y),
                "case {case}: {t:?} has a parent that fit"
            );
        }
        let splits = p.stats.splits_for_importance + p.stats.splits_for_memory;
        let dark_children = count_dark_children(&planner, &m.0);
        assert_eq!(1 + 3 * splits, p.tiles.len() + dark_children, "case {case}");
    }
}

/// Children of split tiles that are skipped for having no importance.
fn count_dark_children(planner: &TilePlanner, importance: &MipChain) -> usize {
    if importance.get(importance.top_level(), 0, 0) == 0.0 {
        return 1; // the root itself
    }
    let mut dark = 0;
    for level in 1..=importance.top_level() {
        let side = importance.level_side(level);
        for y in 0..side {
            for x in 0..side {
                let split = planner.rays_needed(level, x, y) > planner.ray_bound(level, x, y);
                if split && is_reached(planner, level, x, y) {
                    dark += QUADRANTS
                        .iter()
                        .filter(|(dx, dy)| importance.get(level - 1, 2 * x + dx, 2 * y + dy) == 0.0)
                        .count();
                }
            }
        }
    }
    dark
}

/// Whether the descent reaches tile (level, x, y): every ancestor was split.
fn is_reached(planner: &TilePlanner, level: u32, x: u32, y: u32) -> bool {
    let top = planner.importance.top_level();
    (level + 1..=top).all(|j| {
        let (ax, ay) = (x >> (j - level), y >> (j - level));
        planner.rays_needed(j, ax, ay) > planner.ray_bound(j, ax, ay)
    })
}

#[test]
fn program_1_form_equals_the_recursive_descent() {
    let mut rng = Rng::new(4, 4);
    for case in 0..CASES {
        let m = random_maps(&mut rng);
        let planner = TilePlanner::new(&m.0, &m.1, random_params(&mut rng, &m)).unwrap();
        assert_eq!(planner.plan_adaptive_per_pixel(), planner.plan_adaptive_recursive(), "case {case}");
    }
}

#[test]
fn random_cases_reach_every_branch() {
    // Guards the property tests above against generators that never exercise a branch.
    let mut rng = Rng::new(1, 1);
    let mut total = PlanStats::default();
    let mut above_finest = 0;
    for _ in 0..CASES {
        let m = random_maps(&mut rng);
        let params = random_params(&mut rng, &m);
        let _ = random_modes(&mut rng, m.0.side());
        let p = plan(&m, params, TilingMode::Adaptive);
        above_finest += p.tiles.iter().filter(|t| t.level > 0).count();
        total.tiles += p.stats.tiles;
        total.splits_for_importance += p.stats.splits_for_importance;
        total.splits_for_memory += p.stats.splits_for_memory;
        total.undersampled_tiles += p.stats.undersampled_tiles;
    }
    assert!(total.splits_for_importance > 100, "{total:?}");
    assert!(total.splits_for_memory > 100, "{total:?}");
    assert!(total.undersampled_tiles > 100, "{total:?}");
    assert!(above_finest > 1000, "{above_finest} tiles above level 0");
    let finest_met = total.tiles - above_finest - total.undersampled_tiles;
    assert!(finest_met > 1000, "{finest_met} level-0 tiles that met their importance");
}
