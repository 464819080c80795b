//! Region shards through the real binary (docs/SHARDS.md): `bake --shard I/N --shard-by
//! regions` four times and `merge`, round by round, give texel by texel what
//! `bake --bounce-rounds R` gives on one machine, within the bound of docs/SHARDS.md; a
//! missing, duplicated, overlapping or mixed-kind set is one clear error.

mod support;

use std::path::Path;

use support::shards::{OPTIONS, bake, exr, region_bound, scene, worst_relative};
use support::{fails, ok};

fn shards(dir: &Path, out: &str, by: &str, n: u32, extra: &[&str]) -> Vec<String> {
    (0..n)
        .map(|i| {
            let share = format!("{i}/{n}");
            let mut args = vec!["--shard", share.as_str(), "--shard-by", by, "--out", out];
            args.extend(extra);
            bake(dir, &args);
            format!("{out}/shard-{i:04}-of-{n:04}.lbshard")
        })
        .collect()
}

fn merge_args<'a>(files: &[&'a str], out: &'a str) -> Vec<&'a str> {
    let mut a = vec!["-q", "merge"];
    a.extend(files);
    a.extend(["--out", out]);
    a
}

fn merge(dir: &Path, files: &[String], out: &str) {
    let names: Vec<&str> = files.iter().map(String::as_str).collect();
    ok(dir, &merge_args(&names, out));
}

#[test]
fn four_region_shards_merged_match_one_bake_round_by_round() {
    let dir = tempfile::tempdir().expect("temp dir");
    let d = dir.path();
    bake(d, &["--bounce-rounds", "1", "--out", "single1"]);
    bake(d, &["--bounce-rounds", "2", "--out", "single2"]);
    let round1 = shards(d, "r1", "regions", 4, &[]);
    merge(d, &round1, "merged1");
    let worst1 = worst_relative(&exr(&d.join("single1/lightmap_lod0.exr")), &exr(&d.join("merged1/lightmap_lod0.exr")));
    eprintln!("round 1: worst relative difference {worst1:e} (bound {:e})", region_bound(1));
    assert!(worst1 <= region_bound(1), "round 1: {worst1:e} > {:e}", region_bound(1));
    let round2 = shards(d, "r2", "regions", 4, &["--previous", "merged1/merged.lbshard", "--threads", "1"]);
    merge(d, &round2, "merged2");
    let worst2 = worst_relative(&exr(&d.join("single2/lightmap_lod0.exr")), &exr(&d.join("merged2/lightmap_lod0.exr")));
    eprintln!("round 2: worst relative difference {worst2:e} (bound {:e})", region_bound(2));
    assert!(worst2 <= region_bound(2), "round 2: {worst2:e} > {:e}", region_bound(2));
    let (e1, e2) = (exr(&d.join("merged1/lightmap_lod0.exr")), exr(&d.join("merged2/lightmap_lod0.exr")));
    let total = |m: &[[f32; 3]]| m.iter().map(|p| p.iter().map(|&c| c as f64).sum::<f64>()).sum::<f64>();
    assert!(total(&e2) > total(&e1) * 1.05, "round 2 adds no bounce: {} against {}", total(&e2), total(&e1));
    // The report says the round's directions, as a single bake's does.
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.join("merged2/report.json")).expect("report")).expect("JSON");
    assert_eq!(report["lods"][0]["bundle"]["directions"], 64, "{report}");
    // Each region shard holds about a quarter of the texels.
    let texels = |f: &str| {
        let b = std::fs::read(d.join(f)).expect("shard");
        (
            u64::from_le_bytes(b[48..56].try_into().expect("8 bytes")),
            u64::from_le_bytes(b[80..88].try_into().expect("8 bytes")),
        )
    };
    let held: Vec<(u64, u64)> = round2.iter().map(|f| texels(f)).collect();
    let whole = held[0].1;
    assert_eq!(held.iter().map(|h| h.0).sum::<u64>(), whole, "{held:?}");
    for (t, _) in &held {
        assert!(*t as f64 <= whole as f64 / 4.0 * 1.5, "a share of {t} of {whole} texels");
    }
}

/// Round 1's source is the emission the global bundles carry, held by a region shard for
/// the sending texels alone. No bundled scene has an emitter large enough to be carried
/// (their lamps go through the light pass), so the 2 m Cornell room's white walls are made
/// to glow: the shares see each other's glowing walls as the single bake does, to the bit.
#[test]
fn region_shards_see_the_other_shares_carried_emitters() {
    let dir = tempfile::tempdir().expect("temp dir");
    let d = dir.path();
    let source = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/cornell_2m/cornell_2m.gltf");
    let mut gltf: serde_json::Value =
        serde_json::from_slice(&std::fs::read(source).expect("scene")).expect("the scene is JSON");
    let white = gltf["materials"]
        .as_array_mut()
        .and_then(|m| m.iter_mut().find(|m| m["name"] == "white"))
        .expect("a white material");
    white["emissiveFactor"] = serde_json::json!([0.5, 0.4, 0.3]);
    let room = d.join("glowing.gltf");
    std::fs::write(&room, serde_json::to_vec(&gltf).expect("JSON")).expect("write");
    let run = |extra: &[&str]| {
        let mut args = vec!["-q", "bake", room.to_str().expect("UTF-8 path"), "--texel-budget", "20000"];
        args.extend(["--samples", "32"]);
        args.extend(extra);
        ok(d, &args);
    };
    run(&["--bounce-rounds", "1", "--out", "single"]);
    for i in 0..4 {
        run(&["--shard", &format!("{i}/4"), "--shard-by", "regions", "--out", "r"]);
    }
    let files: Vec<String> = (0..4).map(|i| format!("r/shard-{i:04}-of-0004.lbshard")).collect();
    merge(d, &files, "m");
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.join("single/report.json")).expect("report")).expect("JSON");
    let carried = &report["lods"][0]["bundle"]["emitter_triangles_in_global_bundles"];
    assert!(carried.as_u64().is_some_and(|n| n > 0), "no emitter carried by the global bundles: {carried}");
    let worst = worst_relative(&exr(&d.join("single/lightmap_lod0.exr")), &exr(&d.join("m/lightmap_lod0.exr")));
    assert_eq!(worst, 0.0, "region shards' round 1 differs from the single bake's");
}

#[test]
fn region_sets_that_do_not_fit_are_refused() {
    let dir = tempfile::tempdir().expect("temp dir");
    let d = dir.path();
    let set = shards(d, "s", "regions", 4, &[]);
    let names: Vec<&str> = set.iter().map(String::as_str).collect();
    // Missing, twice.
    fails(d, &merge_args(&names[..3], "m"), &["missing 1 of the 4", "shard-0003-of-0004"]);
    fails(d, &merge_args(&[names[0], names[1], names[1], names[2], names[3]], "m"), &["both share 1 of 4"]);
    // Mixed kinds: a direction shard among region shards.
    shards(d, "dir", "directions", 4, &[]);
    fails(
        d,
        &merge_args(&[names[0], names[1], "dir/shard-0002-of-0004.lbshard", names[3]], "m"),
        &["dir/shard-0002", "direction shard", "region shard", "one kind"],
    );
    // Overlapping: share 1 of a set that names share 0's charts (its header rewritten to
    // share 0's charts and texel count, the checksum made again: a consistent file whose
    // charts overlap another's).
    let zero = std::fs::read(d.join(names[0])).expect("shard");
    let one = std::fs::read(d.join(names[1])).expect("shard");
    let mut forged = zero.clone();
    forged[40..44].copy_from_slice(&one[40..44]);
    let body = forged.len() - 8;
    let sum = livebake::shard::WordHash::new();
    let mut sum = sum;
    sum.update(&forged[..body]);
    let value = sum.finish().to_le_bytes();
    forged[body..].copy_from_slice(&value);
    std::fs::write(d.join("overlap.lbshard"), &forged).expect("write");
    fails(d, &merge_args(&[names[0], "overlap.lbshard", names[2], names[3]], "m"), &["both hold chart", "disjoint"]);
    assert!(!d.join("m").exists(), "a refused merge wrote something");
    // A region shard is not a merged round.
    let mut args = vec!["--previous", names[0]];
    args.extend(["--shard", "0/4", "--shard-by", "regions", "--out", "x"]);
    let scene = scene();
    let mut full = vec!["-q", "bake", scene.to_str().expect("UTF-8")];
    full.extend(OPTIONS);
    full.extend(args);
    fails(d, &full, &["not a merged round"]);
    ok(d, &merge_args(&names, "m"));
}
