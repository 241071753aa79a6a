//! Checks of the deployment files against the real program, offline (no Docker engine or cluster
//! runs here): every `bounce` command line in `docker-compose.yml` and `deploy/k8s/` is one this
//! binary's own parser accepts, sharded jobs agree with their `--shard` counts, ports, probes,
//! images and volumes agree with each other, and the probe paths answer on a real server.
//! `.ci/run` also runs `docker-compose config` on the compose files.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use clap::Parser;
use serde_yaml::Value;

use crate::Cli;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn yaml_docs(path: &Path) -> Vec<Value> {
    let text =
        std::fs::read_to_string(path).unwrap_or_else(|e| panic!("reading {}: {e}", path.display()));
    serde_yaml::Deserializer::from_str(&text)
        .map(|d| {
            serde::Deserialize::deserialize(d)
                .unwrap_or_else(|e| panic!("{} is not valid YAML: {e}", path.display()))
        })
        .collect()
}

fn str_of<'a>(v: &'a Value, what: &str) -> &'a str {
    v.as_str()
        .unwrap_or_else(|| panic!("{what} is not a string: {v:?}"))
}

fn strings(v: &Value, what: &str) -> Vec<String> {
    v.as_sequence()
        .unwrap_or_else(|| panic!("{what} is not a list: {v:?}"))
        .iter()
        .map(|s| match s {
            Value::String(s) => s.clone(),
            Value::Number(n) => n.to_string(),
            other => panic!("{what}: {other:?} is not a string"),
        })
        .collect()
}

/// Parses `args` (without the program name) with the real `bounce` parser.
fn parses(args: &[String], where_: &str) -> Cli {
    let argv = std::iter::once("bounce".to_string()).chain(args.iter().cloned());
    Cli::try_parse_from(argv).unwrap_or_else(|e| panic!("{where_}: bounce refuses {args:?}:\n{e}"))
}

/// The value after `flag` in `args`.
fn flag<'a>(args: &'a [String], flag: &str) -> Option<&'a str> {
    args.iter()
        .position(|a| a == flag)
        .and_then(|i| args.get(i + 1))
        .map(String::as_str)
}

fn port_of(addr: &str) -> u16 {
    addr.rsplit(':')
        .next()
        .and_then(|p| p.parse().ok())
        .unwrap_or_else(|| panic!("{addr} has no port"))
}

struct K8s {
    /// (file, document) for every document of every manifest.
    docs: Vec<(String, Value)>,
}

impl K8s {
    fn load() -> K8s {
        let dir = repo().join("deploy/k8s");
        let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
            .expect("deploy/k8s")
            .map(|e| e.expect("entry").path())
            .filter(|p| p.extension().is_some_and(|e| e == "yaml" || e == "yml"))
            .collect();
        files.sort();
        let mut docs = Vec::new();
        for f in files {
            let name = f.file_name().unwrap().to_string_lossy().into_owned();
            for d in yaml_docs(&f) {
                docs.push((name.clone(), d));
            }
        }
        K8s { docs }
    }

    fn of_kind(&self, kind: &str) -> Vec<(&str, &Value)> {
        self.docs
            .iter()
            .filter(|(_, d)| d["kind"].as_str() == Some(kind))
            .map(|(f, d)| (f.as_str(), d))
            .collect()
    }

    fn named(&self, kind: &str, name: &str) -> &Value {
        self.of_kind(kind)
            .into_iter()
            .find(|(_, d)| d["metadata"]["name"].as_str() == Some(name))
            .map(|(_, d)| d)
            .unwrap_or_else(|| panic!("no {kind} named {name} in deploy/k8s"))
    }
}

/// The containers of a workload's pod template.
fn containers(workload: &Value) -> &Vec<Value> {
    workload["spec"]["template"]["spec"]["containers"]
        .as_sequence()
        .expect("a pod template with containers")
}

/// The image's entrypoint is `bounce`, so `args` are bounce's arguments; a `command` would
/// replace the entrypoint.
fn bounce_args(container: &Value, where_: &str) -> Vec<String> {
    assert!(
        container.get("command").is_none(),
        "{where_}: the image's entrypoint is bounce; give `args`, not `command`"
    );
    strings(&container["args"], &format!("{where_} args"))
}

fn compose() -> Value {
    yaml_docs(&repo().join("docker-compose.yml"))
        .into_iter()
        .next()
        .expect("a compose document")
}

#[test]
fn every_manifest_is_a_known_kind_with_a_name() {
    let k8s = K8s::load();
    let kinds: BTreeSet<&str> = k8s
        .docs
        .iter()
        .map(|(f, d)| {
            assert!(d["apiVersion"].is_string(), "{f}: no apiVersion");
            if d["kind"] != "Kustomization" {
                assert!(d["metadata"]["name"].is_string(), "{f}: no metadata.name");
            }
            str_of(&d["kind"], &format!("{f} kind"))
        })
        .collect();
    let want: BTreeSet<&str> = [
        "Deployment",
        "Job",
        "Kustomization",
        "PersistentVolumeClaim",
        "Service",
    ]
    .into();
    assert_eq!(kinds, want);
}

#[test]
fn the_sharded_bake_jobs_run_commands_bounce_accepts_in_the_right_phases() {
    use crate::Command;
    use crate::bake::BakeStep;
    let k8s = K8s::load();
    // Phase by phase: the Indexed jobs' --shard count is their completion count, and each phase
    // reads where the one before wrote.
    let ff = k8s.named("Job", "bounce-bake-ff");
    let t = k8s.named("Job", "bounce-bake-transport");
    let merge = k8s.named("Job", "bounce-bake-merge");
    for job in [ff, t] {
        let name = job["metadata"]["name"].as_str().unwrap();
        assert_eq!(job["spec"]["completionMode"], "Indexed", "{name}");
        let completions = job["spec"]["completions"].as_u64().expect("completions");
        assert_eq!(
            job["spec"]["parallelism"].as_u64(),
            Some(completions),
            "{name}"
        );
        let args = bounce_args(&containers(job)[0], name);
        let shard = flag(&args, "--shard").expect("--shard");
        assert_eq!(
            shard.parse::<u64>().ok(),
            Some(completions),
            "{name}: --shard {shard} takes the index from JOB_COMPLETION_INDEX and must be the completion count"
        );
        // Every index the job runs is a shard bounce accepts.
        for i in 0..completions {
            bounce_core::bake::shard::ShardSpec::parse(shard, Some(&i.to_string()))
                .unwrap_or_else(|e| panic!("{name}, index {i}: {e}"));
        }
        let restart = &job["spec"]["template"]["spec"]["restartPolicy"];
        assert!(restart == "Never" || restart == "OnFailure", "{name}");
    }

    let ff_args = bounce_args(&containers(ff)[0], "bounce-bake-ff");
    let Command::Bake(cmd) = parses(&ff_args, "bounce-bake-ff").command else {
        panic!("bounce-bake-ff does not run `bounce bake`");
    };
    assert!(cmd.step.is_none() && cmd.args.shard.is_some(), "phase 1");
    let ff_out = cmd.args.out.clone().expect("-o");

    let t_args = bounce_args(&containers(t)[0], "bounce-bake-transport");
    let Command::Bake(cmd) = parses(&t_args, "bounce-bake-transport").command else {
        panic!("bounce-bake-transport does not run `bounce bake`");
    };
    let Some(BakeStep::Transport(t_cmd)) = cmd.step else {
        panic!("bounce-bake-transport does not run `bounce bake transport`");
    };
    assert_eq!(t_cmd.inputs, vec![ff_out], "phase 2 reads phase 1's shards");

    assert!(merge["spec"].get("completionMode").is_none());
    let m_args = bounce_args(&containers(merge)[0], "bounce-bake-merge");
    let Command::Bake(cmd) = parses(&m_args, "bounce-bake-merge").command else {
        panic!("bounce-bake-merge does not run `bounce bake`");
    };
    let Some(BakeStep::Merge(m_cmd)) = cmd.step else {
        panic!("bounce-bake-merge does not run `bounce bake merge`");
    };
    assert_eq!(
        m_cmd.inputs,
        vec![t_cmd.out],
        "the merge reads phase 2's shards"
    );

    // The merge writes where the server reads.
    let server = k8s.named("Deployment", "bounce-server");
    let s_args = bounce_args(&containers(server)[0], "bounce-server");
    let scenes = flag(&s_args, "--scenes").expect("--scenes");
    assert_eq!(m_cmd.out.parent(), Some(Path::new(scenes)));
    assert_eq!(m_cmd.out.extension().unwrap(), "bounce");
}

/// Every volume a pod mounts is declared, and every claim it names is a manifest here.
#[test]
fn volumes_and_claims_agree() {
    let k8s = K8s::load();
    let claims: BTreeSet<&str> = k8s
        .of_kind("PersistentVolumeClaim")
        .iter()
        .map(|(_, d)| d["metadata"]["name"].as_str().unwrap())
        .collect();
    for kind in ["Job", "Deployment"] {
        for (file, w) in k8s.of_kind(kind) {
            let spec = &w["spec"]["template"]["spec"];
            let volumes = spec["volumes"].as_sequence().expect("volumes");
            let names: BTreeSet<&str> = volumes
                .iter()
                .map(|v| v["name"].as_str().unwrap())
                .collect();
            for v in volumes {
                if let Some(claim) = v["persistentVolumeClaim"]["claimName"].as_str() {
                    assert!(claims.contains(claim), "{file}: no claim {claim}");
                }
            }
            for c in containers(w) {
                for m in c["volumeMounts"].as_sequence().expect("mounts") {
                    let n = m["name"].as_str().unwrap();
                    assert!(names.contains(n), "{file}: mount of undeclared volume {n}");
                }
            }
        }
    }
}

/// The server's ports, probes and GPU request, and the Service in front of it.
#[test]
fn the_server_deployment_probes_and_exposes_its_real_ports() {
    let k8s = K8s::load();
    let server = k8s.named("Deployment", "bounce-server");
    let c = &containers(server)[0];
    let args = bounce_args(c, "bounce-server");
    assert!(matches!(
        parses(&args, "bounce-server"),
        Cli {
            command: crate::Command::Serve(_)
        }
    ));
    let port_named = |name: &str| {
        c["ports"]
            .as_sequence()
            .expect("ports")
            .iter()
            .find(|p| p["name"] == name)
            .and_then(|p| p["containerPort"].as_u64())
            .unwrap_or_else(|| panic!("no container port named {name}"))
    };
    let http = flag(&args, "--http").expect("--http");
    let grpc = flag(&args, "--grpc").expect("--grpc");
    assert!(http.starts_with("0.0.0.0:") && grpc.starts_with("0.0.0.0:"));
    assert_eq!(port_named("http"), u64::from(port_of(http)));
    assert_eq!(port_named("grpc"), u64::from(port_of(grpc)));
    for (probe, path) in [
        ("livenessProbe", "/healthz"),
        ("readinessProbe", "/readyz"),
        ("startupProbe", "/healthz"),
    ] {
        let get = &c[probe]["httpGet"];
        assert_eq!(get["path"], path, "{probe}");
        assert_eq!(get["port"], "http", "{probe}");
    }
    for section in ["requests", "limits"] {
        assert_eq!(
            c["resources"][section]["nvidia.com/gpu"].as_u64(),
            Some(1),
            "GPU {section}"
        );
    }
    let service = k8s.named("Service", "bounce");
    let labels = &server["spec"]["template"]["metadata"]["labels"];
    for (k, v) in service["spec"]["selector"].as_mapping().expect("selector") {
        assert_eq!(&labels[k], v, "the Service selects the server's pods");
    }
    for p in service["spec"]["ports"].as_sequence().expect("ports") {
        port_named(str_of(&p["targetPort"], "targetPort"));
    }
    // Sessions live in one process: clients stay with the replica that has theirs.
    assert_eq!(service["spec"]["sessionAffinity"], "ClientIP");
}

/// One image everywhere, and kustomize lists every long-lived manifest.
#[test]
fn images_agree_and_kustomize_lists_the_long_lived_manifests() {
    let k8s = K8s::load();
    let compose = compose();
    let mut images = BTreeSet::new();
    for kind in ["Job", "Deployment"] {
        for (_, w) in k8s.of_kind(kind) {
            for c in containers(w) {
                images.insert(str_of(&c["image"], "image").to_string());
            }
        }
    }
    for (_, s) in compose["services"].as_mapping().expect("services") {
        images.insert(str_of(&s["image"], "compose image").to_string());
    }
    assert_eq!(images, BTreeSet::from(["bounce:latest".to_string()]));

    let (_, kustomization) = k8s.of_kind("Kustomization")[0];
    let resources = strings(&kustomization["resources"], "resources");
    for r in &resources {
        assert!(repo().join("deploy/k8s").join(r).is_file(), "{r}");
    }
    let long_lived: BTreeSet<String> = k8s
        .docs
        .iter()
        .filter(|(_, d)| d["kind"] != "Job" && d["kind"] != "Kustomization")
        .map(|(f, _)| f.clone())
        .collect();
    assert_eq!(long_lived, resources.into_iter().collect());
}

/// The compose file: bake first, then the server on the ports it publishes and probes.
#[test]
fn the_compose_services_run_commands_bounce_accepts() {
    let c = compose();
    let server = &c["services"]["server"];
    let bake = &c["services"]["bake"];
    assert_eq!(
        server["depends_on"]["bake"]["condition"],
        "service_completed_successfully"
    );
    assert_eq!(
        strings(&bake["entrypoint"], "bake entrypoint"),
        ["bounce-bake-all"]
    );
    let args = strings(&server["command"], "server command");
    assert!(matches!(
        parses(&args, "compose server"),
        Cli {
            command: crate::Command::Serve(_)
        }
    ));
    let http = port_of(flag(&args, "--http").expect("--http"));
    let grpc = port_of(flag(&args, "--grpc").expect("--grpc"));
    let published: Vec<String> = strings(&server["ports"], "ports");
    for port in [http, grpc] {
        assert!(
            published.iter().any(|p| p.ends_with(&format!(":{port}"))),
            "port {port} is not published: {published:?}"
        );
    }
    let test = strings(&server["healthcheck"]["test"], "healthcheck");
    let script = test.last().expect("a healthcheck command");
    assert!(
        script.contains(&format!("/dev/tcp/127.0.0.1/{http}")) && script.contains("GET /readyz"),
        "{script}"
    );
    // The volume the bake writes is the one the server reads.
    let vols = |s: &Value| strings(&s["volumes"], "volumes");
    assert!(vols(bake).iter().any(|v| v.starts_with("baked:/baked")));
    assert!(vols(server).iter().any(|v| v.starts_with("baked:/baked")));
    assert_eq!(flag(&args, "--scenes"), Some("/baked"));
}

/// The probe paths the manifests name answer 200 on a real server, and the compose file's
/// healthcheck (bash's /dev/tcp, as the image runs it) passes against it.
#[test]
fn the_probes_answer_on_a_real_server() {
    use bounce_core::bake::{BakeOptions, NoProgress, bake_file};
    use bounce_core::voxel::Resolution;
    use std::io::{Read, Write};

    let dir = tempfile::tempdir().unwrap();
    let options = BakeOptions {
        resolution: Resolution::TargetPatches(200),
        rays: 64,
        ..BakeOptions::default()
    };
    bake_file(
        &repo().join("assets/cornell-box/scene.gltf"),
        &options,
        &NoProgress,
    )
    .expect("bake")
    .write_atomic(&dir.path().join("cornell-box.bounce"))
    .expect("write");
    let config = bounce_server::HubConfig::new(dir.path(), bounce_engine::EngineChoice::Cpu);
    let hub = bounce_server::Hub::start(&config).expect("hub");
    let runtime = tokio::runtime::Runtime::new().unwrap();
    let listener = runtime
        .block_on(tokio::net::TcpListener::bind("127.0.0.1:0"))
        .unwrap();
    let addr = listener.local_addr().unwrap();
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let served = runtime.spawn(bounce_server::run(
        hub,
        bounce_server::Listeners::http_only(listener),
        async {
            let _ = stopped.await;
        },
    ));

    let status = |path: &str| {
        let mut s = std::net::TcpStream::connect(addr).expect("connect");
        write!(s, "GET {path} HTTP/1.0\r\n\r\n").unwrap();
        let mut answer = String::new();
        s.read_to_string(&mut answer).unwrap();
        answer.split_whitespace().nth(1).unwrap_or("").to_string()
    };
    let k8s = K8s::load();
    let c = &containers(k8s.named("Deployment", "bounce-server"))[0];
    for probe in ["livenessProbe", "readinessProbe", "startupProbe"] {
        let path = str_of(&c[probe]["httpGet"]["path"], probe);
        assert_eq!(status(path), "200", "{probe} {path}");
    }
    assert_eq!(status("/no-such-path"), "404", "the check can fail");

    // The healthcheck as the container runs it, `$$` being compose's escape for `$`.
    let test = strings(
        &compose()["services"]["server"]["healthcheck"]["test"],
        "test",
    );
    assert_eq!(test[..3], ["CMD", "bash", "-c"]);
    let script = test[3]
        .replace("$$", "$")
        .replace("/8080", &format!("/{}", addr.port()));
    let ok = std::process::Command::new("bash")
        .args(["-c", &script])
        .status()
        .expect("bash runs");
    assert!(
        ok.success(),
        "the compose healthcheck fails on a ready server"
    );
    let wrong = script.replace("/readyz", "/no-such-path");
    let refused = std::process::Command::new("bash")
        .args(["-c", &wrong])
        .status()
        .expect("bash runs");
    assert!(!refused.success(), "the healthcheck passes on a 404");

    let _ = stop.send(());
    runtime.block_on(served).unwrap().unwrap();
}
