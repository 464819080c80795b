//! Counters and phase timings of bundle passes: the paper's Table 1 (time per phase per
//! direction) and Table 2 (overflow and false-alarm ratios), identical for every backend.

use serde::{Deserialize, Serialize};

use super::tiles::PlanStats;

/// Sums over the directions a backend traced.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct PassStats {
    pub directions: u64,
    /// Phase times, seconds summed over directions (divide by `directions` for Table 1).
    pub analysis_seconds: f64,
    pub mip_seconds: f64,
    pub subdivision_seconds: f64,
    /// Build: triangle setup and the exact fragment count (the node-budget check). The CPU
    /// backend builds per-pixel lists row by row while resolving, so its resolve includes
    /// building them.
    pub build_seconds: f64,
    pub resolve_seconds: f64,
    pub light_seconds: f64,
    /// Global-bundle tiles built (after overflow splits).
    pub tiles: u64,
    pub fragments: u64,
    /// Bundle pixels with at least one fragment: effective rays. The CPU backend counts
    /// those it resolves, within each row's hull of the spans that can show a target texel
    /// (in a windowed pass, of the spans' triangles' parts inside the target's box);
    /// the GPU backend all of them: equal when every lit chart is in the target (a whole
    /// LOD).
    pub covered_pixels: u64,
    /// Largest fragment count of any built tile (≤ N unless a single pixel exceeded it).
    pub peak_tile_fragments: u64,
    /// Most hits one unit of the CPU backend (a tile with its parts after an overflow, or a
    /// light bundle) traced ahead of its turn kept as records (20 B each) until then.
    pub peak_recorded_hits: u64,
    /// Tiles whose actual fragment count exceeded N (detected, split and redone).
    pub overflowed_tiles: u64,
    /// Fragments beyond N in those tiles: what a fixed node buffer would have lost.
    pub overflow_fragments: u64,
    pub resplits: u64,
    /// Tiles of one pixel deeper than N, built anyway.
    pub unsplittable_tiles: u64,
    /// Directions whose tiles could not be planned (invalid maps or parameters): their
    /// samples are missing, so a bake with any is refused.
    pub unplanned_directions: u64,
    /// Planner decisions summed over directions.
    pub tiles_planned: u64,
    pub splits_for_importance: u64,
    pub splits_for_memory: u64,
    pub undersampled_tiles: u64,
    /// Memory splits re-counted at the resolution they asked for, and how many would have
    /// fitted after all.
    pub memory_splits_checked: u64,
    pub false_alarms: u64,
    pub light_tiles: u64,
    pub light_fragments: u64,
    /// Light-bundle pixels whose line crosses the emitter group: the light pass's effective
    /// rays (counted apart from the global bundles' `covered_pixels`).
    pub light_covered_pixels: u64,
    /// Fragments whose UV missed every texel through rounding (they still occlude).
    pub lost_lookups: u64,
    /// Foreign sides (surfaces outside the target) whose radiance a target side saw.
    pub foreign_lookups: u64,
    /// GPU backend: pixels deeper than its resolve can sort (skipped; 0 on every scene we
    /// bundle), batches redone because a fixed-point sum saturated, and sums that saturated
    /// even after that.
    pub unresolved_pixels: u64,
    pub redone_batches: u64,
    pub saturated_sums: u64,
    /// GPU backend: submissions of directions' plans (a batch's directions together), each
    /// followed by the read-back of their plans; and submissions of tiles (the planned ones
    /// of those directions, then the parts of overflowed ones), each with one read-back of
    /// their node counts.
    pub plan_submissions: u64,
    pub tile_rounds: u64,
    /// GPU backend: batches it traced on the CPU backend instead (a GPU error, logged; or a
    /// foreign source its resolve has no kernel for).
    pub cpu_fallback_batches: u64,
}

impl PassStats {
    pub fn add_plan(&mut self, p: &PlanStats) {
        self.tiles_planned += p.tiles as u64;
        self.splits_for_importance += p.splits_for_importance as u64;
        self.splits_for_memory += p.splits_for_memory as u64;
        self.undersampled_tiles += p.undersampled_tiles as u64;
    }

    pub fn add(&mut self, o: &PassStats) {
        self.directions += o.directions;
        self.analysis_seconds += o.analysis_seconds;
        self.mip_seconds += o.mip_seconds;
        self.subdivision_seconds += o.subdivision_seconds;
        self.build_seconds += o.build_seconds;
        self.resolve_seconds += o.resolve_seconds;
        self.light_seconds += o.light_seconds;
        self.tiles += o.tiles;
        self.fragments += o.fragments;
        self.covered_pixels += o.covered_pixels;
        self.peak_tile_fragments = self.peak_tile_fragments.max(o.peak_tile_fragments);
        self.peak_recorded_hits = self.peak_recorded_hits.max(o.peak_recorded_hits);
        self.overflowed_tiles += o.overflowed_tiles;
        self.overflow_fragments += o.overflow_fragments;
        self.resplits += o.resplits;
        self.unsplittable_tiles += o.unsplittable_tiles;
        self.unplanned_directions += o.unplanned_directions;
        self.tiles_planned += o.tiles_planned;
        self.splits_for_importance += o.splits_for_importance;
        self.splits_for_memory += o.splits_for_memory;
        self.undersampled_tiles += o.undersampled_tiles;
        self.memory_splits_checked += o.memory_splits_checked;
        self.false_alarms += o.false_alarms;
        self.light_tiles += o.light_tiles;
        self.light_fragments += o.light_fragments;
        self.light_covered_pixels += o.light_covered_pixels;
        self.lost_lookups += o.lost_lookups;
        self.foreign_lookups += o.foreign_lookups;
        self.unresolved_pixels += o.unresolved_pixels;
        self.redone_batches += o.redone_batches;
        self.saturated_sums += o.saturated_sums;
        self.plan_submissions += o.plan_submissions;
        self.tile_rounds += o.tile_rounds;
        self.cpu_fallback_batches += o.cpu_fallback_batches;
    }

    /// Paper Table 2: fragments a fixed node buffer would have lost / all fragments.
    pub fn overflow_ratio(&self) -> f64 {
        ratio(self.overflow_fragments, self.fragments + self.overflow_fragments)
    }

    /// Paper Table 2: unnecessary splits / all splits; `None` when splits for memory were
    /// made but not re-counted ([`BundleConfig::measure_false_alarms`](super::BundleConfig) off).
    pub fn false_alarm_ratio(&self) -> Option<f64> {
        let measured = self.splits_for_memory == 0 || self.memory_splits_checked > 0;
        measured.then(|| ratio(self.false_alarms, self.splits_for_importance + self.splits_for_memory))
    }
}

fn ratio(a: u64, b: u64) -> f64 {
    if b == 0 { 0.0 } else { a as f64 / b as f64 }
}
