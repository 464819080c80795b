//! Direction shards through the real binary (docs/SHARDS.md): `bake --shard I/N` four times
//! and `merge` give, texel by texel, what `bake --bounce-rounds R` gives on one machine, up
//! to the order of the float additions (round 1 and, through `--previous`, round 2); a
//! missing, foreign (other scene, other options), duplicated, truncated or damaged shard
//! is one clear error; merging twice writes the same files; a shard killed mid-run leaves
//! nothing `merge DIR/shard-*` would take, and re-running it completes the set.

mod support;

use std::path::Path;

use support::shards::{OPTIONS, bake, exr, round_one_bound, round_two_bound, scene, worst_relative};
use support::{fails, ok};

fn shards(dir: &Path, out: &str, n: u32, extra: &[&str]) -> Vec<String> {
    (0..n)
        .map(|i| {
            let share = format!("{i}/{n}");
            let mut args = vec!["--shard", share.as_str(), "--out", out];
            args.extend(extra);
            bake(dir, &args);
            format!("{out}/shard-{i:04}-of-{n:04}.lbshard")
        })
        .collect()
}

fn merge(dir: &Path, files: &[String], out: &str) {
    let mut args = vec!["-q", "merge"];
    args.extend(files.iter().map(String::as_str));
    args.extend(["--out", out]);
    ok(dir, &args);
}

#[test]
fn four_shards_merged_equal_one_bake_round_by_round() {
    let dir = tempfile::tempdir().expect("temp dir");
    let d = dir.path();
    bake(d, &["--bounce-rounds", "1", "--out", "single1"]);
    bake(d, &["--bounce-rounds", "2", "--out", "single2", "--export-gltf", "single2/scene.gltf"]);
    let round1 = shards(d, "r1", 4, &[]);
    merge(d, &round1, "merged1");
    let worst1 = worst_relative(&exr(&d.join("single1/lightmap_lod0.exr")), &exr(&d.join("merged1/lightmap_lod0.exr")));
    eprintln!("round 1: worst relative difference {worst1:e} (bound {:e})", round_one_bound());
    assert!(worst1 <= round_one_bound(), "round 1: {worst1:e} > {:e}", round_one_bound());
    // Round 2 reads round 1's merge; its shards run with other thread counts (results do
    // not depend on them).
    let round2 = shards(d, "r2", 4, &["--previous", "merged1/merged.lbshard", "--threads", "1"]);
    merge(d, &round2, "merged2");
    let worst2 = worst_relative(&exr(&d.join("single2/lightmap_lod0.exr")), &exr(&d.join("merged2/lightmap_lod0.exr")));
    eprintln!("round 2: worst relative difference {worst2:e} (bound {:e})", round_two_bound());
    assert!(worst2 <= round_two_bound(), "round 2: {worst2:e} > {:e}", round_two_bound());
    // The bounce adds light: round 2 is not round 1 again.
    let (e1, e2) = (exr(&d.join("merged1/lightmap_lod0.exr")), exr(&d.join("merged2/lightmap_lod0.exr")));
    let total = |m: &[[f32; 3]]| m.iter().map(|p| p.iter().map(|&c| c as f64).sum::<f64>()).sum::<f64>();
    assert!(total(&e2) > total(&e1) * 1.05, "round 2 adds no bounce: {} against {}", total(&e2), total(&e1));
    // With --export-gltf the merge writes the export a bake writes: the same files, its
    // light map within the same bound.
    ok(
        d,
        &[
            "-q",
            "merge",
            &round2[0],
            &round2[1],
            &round2[2],
            &round2[3],
            "--out",
            "merged2",
            "--export-gltf",
            "merged2/scene.gltf",
        ],
    );
    let listing = |dir: &str| {
        let mut names: Vec<String> = std::fs::read_dir(d.join(dir))
            .expect("output folder")
            .flatten()
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| n != "merged.lbshard")
            .collect();
        names.sort();
        names
    };
    assert_eq!(listing("merged2"), listing("single2"));
    let exported = |dir: &str| exr(&d.join(dir).join("scene.lightmap.exr"));
    let worst = worst_relative(&exported("single2"), &exported("merged2"));
    assert!(worst <= round_two_bound(), "export: {worst:e} > {:e}", round_two_bound());
    // Merging again writes the same light map and state.
    merge(d, &round2, "again");
    for f in ["lightmap_lod0.exr", "lightmap_lod0.png", "merged.lbshard"] {
        let (a, b) = (std::fs::read(d.join("merged2").join(f)), std::fs::read(d.join("again").join(f)));
        assert!(a.expect(f) == b.expect(f), "{f} differs between two merges");
    }
    // What a bake writes, the report's LOD included.
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.join("merged2/report.json")).expect("report")).expect("JSON");
    assert_eq!(report["lods"][0]["bundle"]["directions"], 64, "{report}");
    // Texels no bundle reached are counted on the merged sums, as the single bake counts
    // them on its own (not the last shard's count).
    let single: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.join("single2/report.json")).expect("report")).expect("JSON");
    let unsampled = |r: &serde_json::Value| r["lods"][0]["bundle"]["unsampled_texels"].clone();
    assert!(unsampled(&single).is_u64(), "{single}");
    assert_eq!(unsampled(&report), unsampled(&single));
}

#[test]
fn shards_that_do_not_belong_together_are_refused() {
    let dir = tempfile::tempdir().expect("temp dir");
    let d = dir.path();
    let set = shards(d, "s", 4, &[]);
    fn args<'a>(files: &[&'a str]) -> Vec<&'a str> {
        let mut a = vec!["merge"];
        a.extend(files);
        a.extend(["--out", "m"]);
        a
    }
    let names: Vec<&str> = set.iter().map(String::as_str).collect();
    // One missing: named, with the file expected.
    fails(d, &args(&names[..3]), &["missing 1 of the 4", "shard-0003-of-0004"]);
    // One given twice.
    fails(d, &args(&[names[0], names[1], names[1], names[2], names[3]]), &["both share 1 of 4"]);
    // Other options (another seed): foreign.
    shards(d, "seed", 4, &["--seed", "7"]);
    fails(
        d,
        &args(&[names[0], names[1], names[2], "seed/shard-0003-of-0004.lbshard"]),
        &["seed/shard-0003", "does not belong"],
    );
    // Another scene: the same box with one material changed, baked from a copy.
    let copy = d.join("box");
    std::fs::create_dir(&copy).expect("dir");
    for f in std::fs::read_dir(scene().parent().expect("folder")).expect("assets") {
        let f = f.expect("entry").path();
        std::fs::copy(&f, copy.join(f.file_name().expect("name"))).expect("copy");
    }
    let gltf = copy.join(scene().file_name().expect("name"));
    let mut doc: serde_json::Value = serde_json::from_slice(&std::fs::read(&gltf).expect("gltf")).expect("JSON");
    let red = &mut doc["materials"][0]["pbrMetallicRoughness"]["baseColorFactor"][0];
    *red = serde_json::json!(red.as_f64().expect("a base colour") * 0.5);
    std::fs::write(&gltf, serde_json::to_vec(&doc).expect("JSON")).expect("write");
    let gltf = gltf.to_str().expect("UTF-8");
    let mut other = vec!["-q", "bake", gltf];
    other.extend(OPTIONS);
    other.extend(["--shard", "2/4", "--out", "other"]);
    ok(d, &other);
    fails(
        d,
        &args(&[names[0], names[1], "other/shard-0002-of-0004.lbshard", names[3]]),
        &["other/shard-0002", "does not belong"],
    );
    // A share of another count.
    shards(d, "three", 3, &[]);
    fails(
        d,
        &args(&[names[0], names[1], names[2], "three/shard-0000-of-0003.lbshard"]),
        &["three/shard-0000", "does not belong"],
    );
    // Truncated, damaged, not a shard file at all.
    let bytes = std::fs::read(d.join(names[2])).expect("shard");
    std::fs::write(d.join("cut.lbshard"), &bytes[..bytes.len() / 2]).expect("write");
    fails(d, &args(&[names[0], names[1], "cut.lbshard", names[3]]), &["cut.lbshard", "truncated"]);
    let mut damaged = bytes.clone();
    let middle = damaged.len() / 2;
    damaged[middle] ^= 0x40;
    std::fs::write(d.join("damaged.lbshard"), &damaged).expect("write");
    fails(d, &args(&[names[0], names[1], "damaged.lbshard", names[3]]), &["damaged.lbshard", "checksum"]);
    std::fs::write(
        d.join("text.lbshard"),
        "not a shard at all, just some text of a reasonable length ....... ...... ....",
    )
    .expect("write");
    fails(d, &args(&[names[0], names[1], "text.lbshard", names[3]]), &["text.lbshard", "not a livebake shard file"]);
    // A header claiming more texels than the file holds: refused from its size, before
    // anything of that size is allocated.
    let mut huge = bytes.clone();
    huge[48..56].copy_from_slice(&(u64::MAX / 64).to_le_bytes());
    huge[80..88].copy_from_slice(&(u64::MAX / 64).to_le_bytes());
    std::fs::write(d.join("huge.lbshard"), &huge).expect("write");
    fails(d, &args(&[names[0], names[1], "huge.lbshard", names[3]]), &["huge.lbshard", "truncated"]);
    assert!(!d.join("m").exists(), "a refused merge wrote something");
    // And the set itself merges.
    ok(d, &args(&names));
}

/// A layout file (docs/SHARDS.md "The layout file"): the first shard given it makes it, the
/// other shards and the merges of both rounds read it (each says which), and the maps are
/// the same bytes as those of the same shards without it; a layout of another bake, or a
/// damaged one, is made again with a warning, never taken. Region shards read it (a merge
/// made it) and merge to the same bytes as without it.
#[test]
fn shards_and_merges_reading_one_layout_write_the_same_maps() {
    let dir = tempfile::tempdir().expect("temp dir");
    let d = dir.path();
    let scene = scene();
    let scene = scene.to_str().expect("UTF-8");
    // Not quiet: each process says whether it read the layout or wrote it.
    let stderr_of = |args: &[&str]| -> String {
        let out = support::livebake(d, args);
        let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
        assert!(out.status.success() && !stderr.contains("panicked"), "livebake {args:?}:\n{stderr}");
        stderr
    };
    let told = |extra: &[&str]| {
        let mut args = vec!["bake", scene];
        args.extend(OPTIONS);
        args.extend(extra);
        stderr_of(&args)
    };
    let merged_told = |files: &[String], out: &str| {
        let mut args = vec!["merge"];
        args.extend(files.iter().map(String::as_str));
        args.extend(["--out", out, "--layout", "layout.lblayout"]);
        stderr_of(&args)
    };
    let same = |a: &str, b: &str| {
        for f in ["lightmap_lod0.exr", "lightmap_lod0.png"] {
            let (x, y) = (std::fs::read(d.join(a).join(f)).expect(f), std::fs::read(d.join(b).join(f)).expect(f));
            assert!(x == y, "{a}/{f} and {b}/{f} differ");
        }
    };
    for (by, tag) in [("directions", "d"), ("regions", "g")] {
        let _ = std::fs::remove_file(d.join("layout.lblayout"));
        let (p1, p2) = (format!("{tag}p1"), format!("{tag}p2"));
        let (l1, l2, m1, m2) = (format!("{tag}l1"), format!("{tag}l2"), format!("{tag}m1"), format!("{tag}m2"));
        let plain = shards(d, &p1, 2, &["--shard-by", by]);
        merge(d, &plain, &format!("{p1}-m"));
        let previous = format!("{p1}-m/merged.lbshard");
        let plain = shards(d, &p2, 2, &["--shard-by", by, "--previous", &previous]);
        merge(d, &plain, &format!("{p2}-m"));
        for (round, out, merged) in [(1, &l1, &m1), (2, &l2, &m2)] {
            let previous = format!("{m1}/merged.lbshard");
            let mut files = Vec::new();
            for i in 0..2 {
                let share = format!("{i}/2");
                let mut extra = vec!["--shard", &share, "--shard-by", by, "--out", out, "--layout", "layout.lblayout"];
                if round == 2 {
                    extra.extend(["--previous", &previous]);
                }
                let stderr = told(&extra);
                // Direction shards make it when it is missing; region shards, which hold
                // no texel attributes, leave it to the merge.
                let expected = match (by, round, i) {
                    ("directions", 1, 0) => "layout written",
                    ("regions", 1, _) => "",
                    _ => "layout read",
                };
                assert!(stderr.contains(expected), "{by} round {round} share {i}: {stderr}");
                if expected.is_empty() {
                    assert!(!stderr.contains("layout"), "{by} round {round} share {i}: {stderr}");
                }
                files.push(format!("{out}/shard-{i:04}-of-0002.lbshard"));
            }
            let stderr = merged_told(&files, merged);
            let expected = if (by, round) == ("regions", 1) { "layout written" } else { "layout read" };
            assert!(stderr.contains(expected), "{by} merge of round {round}: {stderr}");
        }
        same(&format!("{p1}-m"), &m1);
        same(&format!("{p2}-m"), &m2);
    }
    // Another bake's layout (another seed): made again with a warning, and replaced by this
    // bake's; then a damaged one, the same.
    let stderr = told(&["--seed", "7", "--shard", "0/2", "--out", "seed", "--layout", "layout.lblayout"]);
    assert!(stderr.contains("another scene") && stderr.contains("layout written"), "{stderr}");
    let stderr = told(&["--seed", "7", "--shard", "1/2", "--out", "seed", "--layout", "layout.lblayout"]);
    assert!(stderr.contains("layout read"), "{stderr}");
    let mut bytes = std::fs::read(d.join("layout.lblayout")).expect("layout");
    let middle = bytes.len() / 2;
    bytes[middle] ^= 1;
    std::fs::write(d.join("layout.lblayout"), &bytes).expect("write");
    let stderr = told(&["--seed", "7", "--shard", "1/2", "--out", "seed", "--layout", "layout.lblayout"]);
    assert!(stderr.contains("checksum") && stderr.contains("layout written"), "{stderr}");
    // A layout is a shard's or a merge's: a bake on one machine refuses it.
    fails(d, &["bake", scene, "--layout", "layout.lblayout", "--out", "one"], &["required"]);
}

/// A shard killed while it bakes leaves no file a `shard-*` pattern matches; run again, it
/// completes the set.
#[test]
fn a_killed_shard_leaves_nothing_and_its_rerun_completes_the_set() {
    let dir = tempfile::tempdir().expect("temp dir");
    let d = dir.path();
    let scene = scene();
    // 16 times the directions: long enough to be killed while baking.
    let share = |i: u32| {
        let mut args = vec!["-q".to_string(), "bake".into(), scene.to_str().expect("UTF-8").into()];
        args.extend(OPTIONS.iter().map(|s| s.to_string()));
        args[6] = "1024".into();
        args.extend(["--shard".into(), format!("{i}/2"), "--out".into(), "s".into()]);
        args
    };
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_livebake"))
        .args(share(1))
        .current_dir(d)
        .spawn()
        .expect("shard");
    std::thread::sleep(std::time::Duration::from_millis(700));
    let still_running = child.try_wait().expect("wait").is_none();
    child.kill().ok();
    child.wait().ok();
    assert!(still_running, "the shard finished before it could be killed: make it longer");
    let left: Vec<String> = std::fs::read_dir(d.join("s"))
        .map(|r| r.filter_map(|e| e.ok()).map(|e| e.file_name().to_string_lossy().into_owned()).collect())
        .unwrap_or_default();
    assert!(left.iter().all(|f| !f.starts_with("shard-")), "a killed shard left {left:?}");
    // Share 0, and share 1 run again, complete the set.
    for i in [0, 1] {
        let args = share(i);
        ok(d, &args.iter().map(String::as_str).collect::<Vec<_>>());
    }
    merge(d, &["s/shard-0000-of-0002.lbshard".into(), "s/shard-0001-of-0002.lbshard".into()], "m");
    assert!(d.join("m/lightmap_lod0.exr").exists());
}
