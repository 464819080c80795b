//! The cluster files in deploy/ (docs/SHARDS.md): the Kubernetes manifests parse as YAML
//! (python3's yaml, which scripts/test installs) and say what the docs say (an Indexed Job
//! whose pods bake share `$JOB_COMPLETION_INDEX` of as many shares as it has completions, and
//! a merge of that round's shards); the Slurm scripts and their helper parse as bash. The
//! Slurm scripts themselves run in tests/slurm.rs.

use std::path::Path;
use std::process::Command;

use serde_json::Value;

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The documents of a YAML file, through python3's yaml as JSON.
fn yaml(path: &Path) -> Vec<Value> {
    let out = Command::new("python3")
        .args(["-c", "import json, sys, yaml; print(json.dumps(list(yaml.safe_load_all(open(sys.argv[1])))))"])
        .arg(path)
        .output()
        .expect("python3 (scripts/test installs it and python3-yaml)");
    assert!(out.status.success(), "{}: {}", path.display(), String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).expect("JSON from python3")
}

fn container_command(job: &Value) -> String {
    let c = &job["spec"]["template"]["spec"]["containers"][0];
    let parts: Vec<&str> = ["command", "args"]
        .iter()
        .flat_map(|k| c[k].as_array().into_iter().flatten().filter_map(Value::as_str))
        .collect();
    parts.join(" ")
}

#[test]
fn the_kubernetes_jobs_are_an_indexed_bake_and_its_merge() {
    let bake = yaml(&root().join("deploy/k8s/bake-job.yaml"));
    assert_eq!(bake.len(), 1);
    let job = &bake[0];
    assert_eq!((job["apiVersion"].as_str(), job["kind"].as_str()), (Some("batch/v1"), Some("Job")));
    assert_eq!(job["spec"]["completionMode"], "Indexed");
    let completions = job["spec"]["completions"].as_u64().expect("completions");
    let command = container_command(job);
    assert!(
        command.contains(&format!("--shard \"$JOB_COMPLETION_INDEX/{completions}\"")),
        "the pods' shares do not match the {completions} completions: {command}"
    );
    assert!(command.contains("livebake -q bake") && command.contains("--out /work/shards-1"), "{command}");
    assert_eq!(job["spec"]["template"]["spec"]["restartPolicy"], "Never");

    let merge = yaml(&root().join("deploy/k8s/merge-job.yaml"));
    let command = container_command(&merge[0]);
    assert!(command.contains("livebake -q merge /work/shards-1/shard-*"), "{command}");
    // Both mount the same claim at the same place.
    let claim = |j: &Value| j["spec"]["template"]["spec"]["volumes"][0]["persistentVolumeClaim"]["claimName"].clone();
    assert_eq!(claim(job), claim(&merge[0]));
    assert!(claim(job).is_string());
}

#[test]
fn the_slurm_scripts_parse() {
    for script in
        ["deploy/slurm/bake.sbatch", "deploy/slurm/merge.sbatch", "deploy/slurm/submit", "scripts/slurm-local"]
    {
        let status = Command::new("bash").arg("-n").arg(root().join(script)).status().expect("bash");
        assert!(status.success(), "{script} does not parse");
    }
}
