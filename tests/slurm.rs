//! Direction shards on a real scheduler: a one-node Slurm cluster on this machine
//! (`scripts/slurm-local`, which installs Debian's slurm-wlm and munge when missing and is
//! stopped after the test, also when it fails) runs `deploy/slurm/submit`: two bounce rounds
//! of a 4-task job array each, every round merged by a job depending on its array
//! (`afterok`). The merged light map equals `bake --bounce-rounds 2` on one machine within
//! docs/SHARDS.md's bound. Then a task killed mid-run (`scancel`) leaves no shard file, its
//! merge never runs, and re-submitting that index with a new merge completes the bake.

mod support;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use support::ok;
use support::shards::{CORNELL, OPTIONS, exr, round_one_bound, round_two_bound, worst_relative};

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The cluster, stopped when dropped (after a failed assertion too).
struct Cluster {
    dir: PathBuf,
}

impl Cluster {
    fn start(dir: PathBuf) -> Cluster {
        let status = Command::new(root().join("scripts/slurm-local"))
            .arg("start")
            .arg(&dir)
            .status()
            .expect("scripts/slurm-local");
        // Stopped even when the start failed half-way.
        let cluster = Cluster { dir };
        assert!(status.success(), "scripts/slurm-local start failed (see {}/*.log)", cluster.dir.display());
        cluster
    }

    fn command(&self, program: &str) -> Command {
        let mut c = Command::new(program);
        c.env("SLURM_CONF", self.dir.join("slurm.conf")).env("LIVEBAKE", env!("CARGO_BIN_EXE_livebake"));
        c
    }

    /// Runs a client command and returns its standard output.
    fn run(&self, program: &str, args: &[&str], env: &[(&str, &str)]) -> String {
        let out = self.command(program).args(args).envs(env.iter().copied()).output().expect(program);
        let text = String::from_utf8_lossy(&out.stdout).into_owned();
        assert!(out.status.success(), "{program} {args:?}: {}", String::from_utf8_lossy(&out.stderr));
        text
    }

    /// The jobs (and array tasks) still queued or running, with their state and reason.
    fn queue(&self) -> Vec<String> {
        self.run("squeue", &["-h", "-r", "-o", "%i %T %r"], &[]).lines().map(str::to_string).collect()
    }

    /// Waits until no job of `ids` (job ids, arrays included) is queued or running, except
    /// those waiting on a dependency that can never be met, which it returns.
    fn wait(&self, ids: &[&str], timeout: Duration) -> Vec<String> {
        let t = Instant::now();
        loop {
            let job = |l: &str| l.split(' ').next().unwrap_or("").split('_').next().unwrap_or("").to_string();
            let mine: Vec<String> = self.queue().into_iter().filter(|l| ids.contains(&job(l).as_str())).collect();
            if mine.iter().all(|l| l.contains("DependencyNeverSatisfied")) {
                return mine;
            }
            assert!(t.elapsed() < timeout, "jobs still queued after {timeout:?}: {mine:?}\n{}", self.logs());
            std::thread::sleep(Duration::from_millis(250));
        }
    }

    fn logs(&self) -> String {
        let tail = |f: &str| std::fs::read_to_string(self.dir.join(f)).unwrap_or_default();
        let text = tail("slurmctld.log");
        text.lines().rev().take(20).collect::<Vec<_>>().join("\n")
    }
}

impl Drop for Cluster {
    fn drop(&mut self) {
        let _ = Command::new(root().join("scripts/slurm-local")).arg("stop").arg(&self.dir).status();
    }
}

/// The output files of the jobs under `dir`, for a failure's message.
fn job_outputs(dir: &Path) -> String {
    let mut s = String::new();
    for e in std::fs::read_dir(dir).into_iter().flatten().flatten() {
        if e.path().extension().is_some_and(|x| x == "out") {
            s += &format!("{}:\n{}\n", e.path().display(), std::fs::read_to_string(e.path()).unwrap_or_default());
        }
    }
    s
}

#[test]
fn a_job_array_of_shards_and_its_merge_equal_one_bake() {
    let tmp = tempfile::tempdir().expect("temp dir");
    let d = tmp.path();
    let cluster = Cluster::start(d.join("slurm"));
    let scene = root().join(CORNELL);
    let scene = scene.to_str().expect("UTF-8");
    let single = |rounds: &str, out: &str| {
        let mut args = vec!["-q", "bake", scene, "--bounce-rounds", rounds, "--out", out];
        args.extend(OPTIONS);
        ok(d, &args);
    };
    single("1", "single1");
    single("2", "single2");

    // Two rounds of four shards, each round merged after its array.
    let work = d.join("work");
    let work_s = work.to_str().expect("UTF-8");
    let mut args = vec![scene, work_s, "4", "2"];
    args.extend(OPTIONS);
    let submit = root().join("deploy/slurm/submit");
    let last = cluster.run(submit.to_str().expect("UTF-8"), &args, &[]).trim().to_string();
    assert!(last.parse::<u64>().is_ok(), "submit printed {last:?}");
    // Job ids count from 1 on a new cluster: the two arrays and two merges are 1 to 4.
    let left = cluster.wait(&["1", "2", "3", "4"], Duration::from_secs(300));
    assert!(left.is_empty(), "jobs never ran: {left:?}\n{}", job_outputs(&work));
    let merged = work.join("merged-2/lightmap_lod0.exr");
    assert!(merged.exists(), "no merged light map\n{}", job_outputs(&work));
    // Every job was given the bake's layout file: the first made it.
    assert!(work.join("layout.lblayout").is_file(), "no layout file\n{}", job_outputs(&work));
    let worst = worst_relative(&exr(&d.join("single2/lightmap_lod0.exr")), &exr(&merged));
    eprintln!("Slurm, round 2: worst relative difference {worst:e} (bound {:e})", round_two_bound());
    assert!(worst <= round_two_bound(), "{worst:e} > {:e}", round_two_bound());

    // A task killed mid-run: 16 times the directions, so that it is still baking.
    let mut slow: Vec<&str> = OPTIONS.to_vec();
    slow[3] = "1024";
    let shards = d.join("killed");
    let shards_s = shards.to_str().expect("UTF-8");
    let bake_sbatch = root().join("deploy/slurm/bake.sbatch");
    let merge_sbatch = root().join("deploy/slurm/merge.sbatch");
    let (bake_sbatch, merge_sbatch) = (bake_sbatch.to_str().expect("UTF-8"), merge_sbatch.to_str().expect("UTF-8"));
    let chdir = format!("--chdir={}", d.display());
    let mut array_args = vec!["--parsable", "--array=0-3", chdir.as_str(), bake_sbatch, scene, shards_s];
    array_args.extend(&slow);
    let array = cluster.run("sbatch", &array_args, &[]).trim().to_string();
    let after = format!("--dependency=afterok:{array}");
    let merged_dir = d.join("killed-merged");
    let merged_s = merged_dir.to_str().expect("UTF-8");
    let merge = cluster.run("sbatch", &["--parsable", &after, &chdir, merge_sbatch, shards_s, merged_s], &[]);
    let merge = merge.trim().to_string();
    let task = format!("{array}_1");
    let t = Instant::now();
    while !cluster.queue().iter().any(|l| l.starts_with(&format!("{task} RUNNING"))) {
        assert!(t.elapsed() < Duration::from_secs(120), "task {task} never ran: {:?}", cluster.queue());
        std::thread::sleep(Duration::from_millis(100));
    }
    // Half a second into its bake (its share takes seconds).
    std::thread::sleep(Duration::from_millis(500));
    assert!(cluster.queue().iter().any(|l| l.starts_with(&format!("{task} RUNNING"))), "task {task} ended too soon");
    cluster.run("scancel", &[&task], &[]);
    let left = cluster.wait(&[&array, &merge], Duration::from_secs(300));
    // The merge waits for a dependency that can no longer be met: it never runs.
    assert!(left.iter().any(|l| l.starts_with(&merge)), "the merge ran or vanished: {left:?}");
    assert!(!merged_dir.exists(), "the merge ran without share 1");
    let names: Vec<String> = std::fs::read_dir(&shards)
        .expect("shard folder")
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    assert!(!names.iter().any(|n| n.starts_with("shard-0001")), "the killed task left {names:?}");
    assert_eq!(names.iter().filter(|n| n.starts_with("shard-")).count(), 3, "{names:?}");
    cluster.run("scancel", &[&merge], &[]);
    // Index 1 again (of 4), and a new merge after it.
    let again_args = {
        let mut a = vec!["--parsable", "--array=1", chdir.as_str(), bake_sbatch, scene, shards_s];
        a.extend(&slow);
        a
    };
    let again = cluster.run("sbatch", &again_args, &[("LIVEBAKE_SHARDS", "4")]).trim().to_string();
    let after = format!("--dependency=afterok:{again}");
    let merge = cluster.run("sbatch", &["--parsable", &after, &chdir, merge_sbatch, shards_s, merged_s], &[]);
    let left = cluster.wait(&[&again, merge.trim()], Duration::from_secs(300));
    assert!(left.is_empty(), "jobs never ran: {left:?}\n{}", job_outputs(d));
    let merged = merged_dir.join("lightmap_lod0.exr");
    assert!(merged.exists(), "the re-submitted set did not merge\n{}", job_outputs(d));
    // Against one machine's round 1 at the same directions.
    let mut args = vec!["-q", "bake", scene, "--bounce-rounds", "1", "--out", "single-slow"];
    args.extend(&slow);
    ok(d, &args);
    let worst = worst_relative(&exr(&d.join("single-slow/lightmap_lod0.exr")), &exr(&merged));
    // 1024 directions are 128 batches of 8: the round-1 bound scaled to them.
    let bound = round_one_bound() * (128.0 + 2.0) / (support::shards::BATCHES + 2.0);
    assert!(worst <= bound, "{worst:e} > {bound:e}");
}
