//! The fleet across hosts over zenoh (`--features zenoh`; docs/fleet.md): two network
//! namespaces joined by a veth pair stand for two hosts, the learner (`mpo train
//! --plants-remote 1 --fleet-listen ...`) in one, a plant (`mpo plant-worker --fleet-connect
//! ...`) in the other. A deterministic run over zenoh gives the bits of the same run over
//! iceoryx2; so does one with mutual TLS, after refusing a plant whose certificate another CA
//! signed; one whose link goes down for 3 s mid-run; and one of two plants whose learner is
//! killed and resumed (the plants join the resumed learner; the bits of the uninterrupted run).
//!
//! Needs root (`ip netns add`): CI runs as root. Without it the tests fail, saying so. Each
//! test removes its namespaces (and with them the veth pair) when it ends, failed or not, and
//! every process it starts has a deadline.

#![cfg(feature = "zenoh")]

mod common;

use std::io::{BufRead, BufReader, Read};
use std::path::Path;
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use common::{ok_json, scratch, tiny};

/// The learner's address (its namespace's end of the veth pair) and the plant's.
const LEARNER_IP: &str = "10.77.0.1";
const PLANT_IP: &str = "10.77.0.2";
/// No process of these tests runs longer.
const DEADLINE: Duration = Duration::from_secs(300);

fn ip(args: &[&str]) -> Result<(), String> {
    let out = Command::new("ip")
        .args(args)
        .output()
        .map_err(|e| format!("ip {}: {e}", args.join(" ")))?;
    match out.status.success() {
        true => Ok(()),
        false => Err(format!(
            "ip {}: {}",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr).trim()
        )),
    }
}

/// Two network namespaces joined by a veth pair (10.77.0.1/24 in the learner's, .2 in the
/// plant's); removed on drop.
struct Hosts {
    learner: String,
    plant: String,
    /// The learner's end of the veth pair (in its namespace).
    veth: String,
}

impl Hosts {
    /// Creates the namespaces of test `tag` (one letter); panics with why when it cannot.
    fn new(tag: &str) -> Self {
        remove_stale();
        let pid = std::process::id();
        let h = Self {
            learner: format!("mpoz{pid}{tag}l"),
            plant: format!("mpoz{pid}{tag}p"),
            veth: format!("mz{pid}{tag}l"),
        };
        let peer = format!("mz{pid}{tag}p");
        let steps: [Vec<&str>; 3] = [
            vec!["netns", "add", &h.learner],
            vec!["netns", "add", &h.plant],
            vec![
                "link", "add", &h.veth, "netns", &h.learner, "type", "veth", "peer", "name", &peer,
                "netns", &h.plant,
            ],
        ];
        for s in &steps {
            if let Err(e) = ip(s) {
                drop(h);
                panic!(
                    "cannot set up the two network namespaces this test needs ({e}): it must \
                     run as root (`ip netns add`), as CI does; it does not pass without them"
                );
            }
        }
        let ln = format!("{LEARNER_IP}/24");
        let pn = format!("{PLANT_IP}/24");
        let config: [Vec<&str>; 6] = [
            vec!["-n", &h.learner, "addr", "add", &ln, "dev", &h.veth],
            vec!["-n", &h.plant, "addr", "add", &pn, "dev", &peer],
            vec!["-n", &h.learner, "link", "set", "lo", "up"],
            vec!["-n", &h.plant, "link", "set", "lo", "up"],
            vec!["-n", &h.learner, "link", "set", &h.veth, "up"],
            vec!["-n", &h.plant, "link", "set", &peer, "up"],
        ];
        for s in &config {
            ip(s).unwrap_or_else(|e| panic!("configuring the namespaces: {e}"));
        }
        h
    }

    /// `ip netns exec NS mpo ARGS`.
    fn mpo(&self, learner: bool, args: &[&str]) -> Proc {
        let ns = match learner {
            true => &self.learner,
            false => &self.plant,
        };
        let mut c = Command::new("ip");
        c.args(["netns", "exec", ns, env!("CARGO_BIN_EXE_mpo")])
            .args(args);
        Proc::spawn(c)
    }

    /// Sets the learner's end of the link down (`false`) or up.
    fn link(&self, up: bool) {
        let state = if up { "up" } else { "down" };
        ip(&["-n", &self.learner, "link", "set", &self.veth, state])
            .unwrap_or_else(|e| panic!("{e}"));
    }
}

impl Drop for Hosts {
    fn drop(&mut self) {
        // Deleting a namespace deletes its end of the veth pair, and with it the pair.
        let _ = ip(&["netns", "del", &self.learner]);
        let _ = ip(&["netns", "del", &self.plant]);
    }
}

/// Removes the namespaces an earlier run of these tests left when it was killed (their
/// process is gone).
fn remove_stale() {
    let Ok(out) = Command::new("ip").args(["netns", "list"]).output() else {
        return;
    };
    for line in String::from_utf8_lossy(&out.stdout).lines() {
        let name = line.split_whitespace().next().unwrap_or("");
        let Some(rest) = name.strip_prefix("mpoz") else {
            continue;
        };
        let pid: String = rest.chars().take_while(|c| c.is_ascii_digit()).collect();
        if !pid.is_empty() && !Path::new(&format!("/proc/{pid}")).exists() {
            let _ = ip(&["netns", "del", name]);
        }
    }
}

/// A process with its output collected as it comes, killed on drop.
struct Proc {
    child: Option<Child>,
    stdout: Option<std::thread::JoinHandle<String>>,
    stderr: Arc<Mutex<String>>,
    reader: Option<std::thread::JoinHandle<()>>,
    started: Instant,
}

impl Proc {
    fn spawn(mut c: Command) -> Self {
        let mut child = c
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("spawn ip netns exec");
        let mut out = child.stdout.take().unwrap();
        let stdout = std::thread::spawn(move || {
            let mut s = String::new();
            let _ = out.read_to_string(&mut s);
            s
        });
        let err = BufReader::new(child.stderr.take().unwrap());
        let stderr = Arc::new(Mutex::new(String::new()));
        let log = stderr.clone();
        let reader = std::thread::spawn(move || {
            for line in err.lines().map_while(Result::ok) {
                let mut l = log.lock().unwrap();
                l.push_str(&line);
                l.push('\n');
            }
        });
        Self {
            child: Some(child),
            stdout: Some(stdout),
            stderr,
            reader: Some(reader),
            started: Instant::now(),
        }
    }

    fn log(&self) -> String {
        self.stderr.lock().unwrap().clone()
    }

    /// Waits until its stderr holds `what` (panics past `within`, or when it exited).
    fn wait_for(&mut self, what: &str, within: Duration) {
        let t0 = Instant::now();
        while !self.log().contains(what) {
            if let Ok(Some(st)) = self.child.as_mut().unwrap().try_wait() {
                std::thread::sleep(Duration::from_millis(200));
                panic!("exited ({st}) before saying {what:?}:\n{}", self.log());
            }
            assert!(
                t0.elapsed() < within,
                "{what:?} not said within {within:?}:\n{}",
                self.log()
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// Waits for it to exit (killing it past [`DEADLINE`]): status, stdout, stderr.
    fn finish(mut self) -> (ExitStatus, String, String) {
        let mut child = self.child.take().unwrap();
        let status = loop {
            if let Some(st) = child.try_wait().unwrap() {
                break st;
            }
            if self.started.elapsed() > DEADLINE {
                let _ = child.kill();
                let _ = child.wait();
                panic!("still running after {DEADLINE:?}; killed:\n{}", self.log());
            }
            std::thread::sleep(Duration::from_millis(50));
        };
        let stdout = self.stdout.take().unwrap().join().unwrap();
        self.reader.take().unwrap().join().unwrap();
        (status, stdout, self.log())
    }

    /// True while it runs.
    fn running(&mut self) -> bool {
        matches!(self.child.as_mut().unwrap().try_wait(), Ok(None))
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

fn sha(v: &serde_json::Value) -> &str {
    v["params_sha256"].as_str().unwrap()
}

/// The learner's `mpo train` arguments: the tiny cartpole row, `steps` steps, K = 10,
/// waiting for one plant on `listen`, run id `run`.
fn learner_args(dir: &Path, steps: &str, listen: &str, run: &str) -> Vec<String> {
    let mut a: Vec<String> = ["train", "--net", "tiny", "--no-progress", "--steps", steps]
        .iter()
        .map(|s| s.to_string())
        .collect();
    a.extend(
        [
            "--sync-every",
            "10",
            "--plants-remote",
            "1",
            "--fleet-listen",
            listen,
        ]
        .map(String::from),
    );
    a.extend(["--fleet-run", run, "--plant-timeout", "60", "--out"].map(String::from));
    a.push(dir.to_str().unwrap().into());
    a
}

/// The plant's `mpo plant-worker` arguments.
fn plant_args(connect: &str, run: &str) -> Vec<String> {
    [
        "plant-worker",
        "--task",
        "cartpole-balance",
        "--net",
        "tiny",
        "--index",
        "0",
    ]
    .iter()
    .chain(&[
        "--run",
        run,
        "--fleet-connect",
        connect,
        "--block-hint",
        "10",
    ])
    .map(|s| s.to_string())
    .collect()
}

fn strs(v: &[String]) -> Vec<&str> {
    v.iter().map(String::as_str).collect()
}

/// The learner's summary (panics with both logs unless the learner and the plant succeeded).
fn summary(learner: Proc, plant: Proc) -> serde_json::Value {
    let (st, out, log) = learner.finish();
    let (pst, _, plog) = plant.finish();
    assert!(
        st.success() && pst.success(),
        "learner {st}:\n{log}\nplant {pst}:\n{plog}"
    );
    serde_json::from_str(out.trim()).unwrap_or_else(|e| panic!("{e}: {out}\n{log}"))
}

/// The same run over iceoryx2: `--plants 1 --sync-every 10`.
fn over_iceoryx2(dir: &Path, steps: u64) -> serde_json::Value {
    ok_json(&tiny(dir, steps, &["--plants", "1", "--sync-every", "10"]))
}

#[test]
#[ignore = "long: two network namespaces (root), two tiny fleet runs over zenoh and iceoryx2"]
fn a_plant_in_another_namespace_trains_the_bits_of_the_iceoryx2_run() {
    let dir = scratch("zenoh-tcp");
    let hosts = Hosts::new("a");
    let listen = format!("tcp/{LEARNER_IP}:7447");
    let run = "zenoh-tcp-test";
    let learner = hosts.mpo(
        true,
        &strs(&learner_args(&dir.join("zenoh"), "2000", &listen, run)),
    );
    let plant = hosts.mpo(false, &strs(&plant_args(&listen, run)));
    let t0 = Instant::now();
    let s = summary(learner, plant);
    let took = t0.elapsed();
    let local = over_iceoryx2(&dir.join("iceoryx2"), 2000);
    assert_eq!(sha(&s), sha(&local), "{s}\n{local}");
    assert_eq!(s["updates"], local["updates"]);
    assert_eq!(s["fleet"]["transitions"], 2000);
    assert_eq!(s["fleet"]["dropped"], 0);
    // The throughput of the two transports (the tiny row: the learner's updates dominate).
    let rate = |v: &serde_json::Value| 2000.0 / v["wall_s"].as_f64().unwrap();
    eprintln!(
        "over zenoh between namespaces: {took:.1?} in all, {:.0} steps/s inserted; over \
         iceoryx2 {:.0} steps/s; parameter latency {:.0} us mean, {:.0} us max over zenoh",
        rate(&s),
        rate(&local),
        s["fleet"]["param_latency_us_mean"].as_f64().unwrap_or(0.0),
        s["fleet"]["param_latency_us_max"].as_f64().unwrap_or(0.0),
    );
}

/// Makes a CA and certificates with `openssl` in `dir`: `ca` (the fleet's), `learner` (its
/// address as subjectAltName), `plant`, and `rogue` (a plant certificate of another CA).
fn certificates(dir: &Path) {
    let run = |args: &[&str]| {
        let out = Command::new("openssl")
            .args(args)
            .current_dir(dir)
            .output()
            .expect("openssl (Debian's openssl package)");
        assert!(
            out.status.success(),
            "openssl {}: {}",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr)
        );
    };
    let ec = [
        "-newkey",
        "ec",
        "-pkeyopt",
        "ec_paramgen_curve:prime256v1",
        "-nodes",
    ];
    for ca in ["ca", "rogue-ca"] {
        let subj = format!("/CN=mpo fleet test {ca}");
        let (key, pem) = (format!("{ca}.key"), format!("{ca}.pem"));
        let mut a = vec![
            "req", "-x509", "-days", "2", "-subj", &subj, "-keyout", &key,
        ];
        a.extend(ec);
        a.extend(["-out", &pem, "-addext", "basicConstraints=critical,CA:TRUE"]);
        a.extend(["-addext", "keyUsage=critical,keyCertSign,cRLSign"]);
        run(&a);
    }
    for (name, ca, san) in [
        ("learner", "ca", format!("IP:{LEARNER_IP}")),
        ("plant", "ca", format!("IP:{PLANT_IP}")),
        ("rogue", "rogue-ca", format!("IP:{PLANT_IP}")),
    ] {
        let ext = format!(
            "basicConstraints=CA:FALSE\nkeyUsage=critical,digitalSignature\n\
             extendedKeyUsage=serverAuth,clientAuth\nsubjectAltName={san}\n"
        );
        std::fs::write(dir.join(format!("{name}.ext")), ext).unwrap();
        let subj = format!("/CN=mpo fleet test {name}");
        let (key, csr) = (format!("{name}.key"), format!("{name}.csr"));
        let mut a = vec!["req", "-new", "-subj", &subj, "-keyout", &key, "-out", &csr];
        a.extend(ec);
        run(&a);
        let (ca_pem, ca_key) = (format!("{ca}.pem"), format!("{ca}.key"));
        let (pem, ext) = (format!("{name}.pem"), format!("{name}.ext"));
        run(&[
            "x509",
            "-req",
            "-days",
            "2",
            "-in",
            &csr,
            "-CA",
            &ca_pem,
            "-CAkey",
            &ca_key,
            "-CAcreateserial",
            "-extfile",
            &ext,
            "-out",
            &pem,
        ]);
    }
}

fn tls_args(dir: &Path, name: &str) -> Vec<String> {
    let f = |n: &str| dir.join(n).to_str().unwrap().to_string();
    vec![
        "--fleet-ca".into(),
        f("ca.pem"),
        "--fleet-cert".into(),
        f(&format!("{name}.pem")),
        "--fleet-key".into(),
        f(&format!("{name}.key")),
    ]
}

#[test]
#[ignore = "long: two network namespaces (root), mutual TLS, a refused plant and two tiny runs"]
fn mutual_tls_refuses_a_plant_of_another_ca_and_trains_with_its_own() {
    let dir = scratch("zenoh-tls");
    let certs = dir.join("certs");
    std::fs::create_dir_all(&certs).unwrap();
    certificates(&certs);
    let hosts = Hosts::new("b");
    let listen = format!("tls/{LEARNER_IP}:7447");
    let run = "zenoh-tls-test";
    let mut a = learner_args(&dir.join("zenoh"), "2000", &listen, run);
    a.extend(tls_args(&certs, "learner"));
    let mut learner = hosts.mpo(true, &strs(&a));
    learner.wait_for("waiting", Duration::from_secs(60));
    // A plant whose certificate another CA signed (it trusts the fleet's CA, so only the
    // learner's check of its certificate stops it): it never joins, and gives up.
    let mut rogue = plant_args(&listen, run);
    rogue.extend(tls_args(&certs, "rogue"));
    rogue.extend(["--fleet-connect-timeout".into(), "8".into()]);
    let (st, _, rlog) = hosts.mpo(false, &strs(&rogue)).finish();
    assert_eq!(st.code(), Some(1), "the rogue plant: {st}\n{rlog}");
    assert!(rlog.contains("reaching the learner at tls/"), "{rlog}");
    assert!(!learner.log().contains("joined"), "{}", learner.log());
    // A plant without any certificate cannot even be configured for a tls/ endpoint.
    let (st, _, nlog) = hosts.mpo(false, &strs(&plant_args(&listen, run))).finish();
    assert_eq!(st.code(), Some(1), "{nlog}");
    assert!(nlog.contains("needs certificates"), "{nlog}");
    // The fleet's own plant.
    let mut good = plant_args(&listen, run);
    good.extend(tls_args(&certs, "plant"));
    let plant = hosts.mpo(false, &strs(&good));
    let s = summary(learner, plant);
    let local = over_iceoryx2(&dir.join("iceoryx2"), 2000);
    assert_eq!(sha(&s), sha(&local), "{s}\n{local}");
    assert_eq!(s["fleet"]["refused"], 0);
}

#[test]
#[ignore = "long: two network namespaces (root), a link down for 3 s in a paced tiny run"]
fn a_link_down_for_three_seconds_is_survived_with_the_same_bits() {
    let dir = scratch("zenoh-drop");
    let hosts = Hosts::new("c");
    let listen = format!("tcp/{LEARNER_IP}:7447");
    let run = "zenoh-drop-test";
    let mut learner = hosts.mpo(
        true,
        &strs(&learner_args(&dir.join("zenoh"), "3000", &listen, run)),
    );
    // Paced at 300 steps/s, the run lasts 10 s or more: long enough for the drop.
    let mut p = plant_args(&listen, run);
    p.extend(["--rate".into(), "300".into()]);
    let plant = hosts.mpo(false, &strs(&p));
    learner.wait_for("fleet: plant 0 joined", Duration::from_secs(60));
    std::thread::sleep(Duration::from_secs(2));
    hosts.link(false);
    std::thread::sleep(Duration::from_secs(3));
    hosts.link(true);
    assert!(
        learner.running(),
        "the run ended before the link came back: make it longer"
    );
    let s = summary(learner, plant);
    let local = over_iceoryx2(&dir.join("iceoryx2"), 3000);
    assert_eq!(sha(&s), sha(&local), "{s}\n{local}");
    assert_eq!(s["fleet"]["dropped"], 0);
    assert_eq!(s["fleet"]["transitions"], 3000);
}

#[test]
#[ignore = "long: two network namespaces (root), a learner killed and resumed with two plants"]
fn two_plants_follow_a_learner_killed_and_resumed_to_the_uninterrupted_bits() {
    let dir = scratch("zenoh-resume");
    let hosts = Hosts::new("d");
    let listen = format!("tcp/{LEARNER_IP}:7447");
    let run = "zenoh-resume-test";
    let out = dir.join("zenoh");
    // Two plants, K = 10, a checkpoint every 2000 steps: at 2000 both plants' first episodes
    // have ended, so the resumed run is the uninterrupted one.
    let eval = ["--set", "schedule.eval_interval=2000"];
    let mut args = learner_args(&out, "4000", &listen, run);
    let n = args.iter().position(|a| a == "--plants-remote").unwrap();
    args[n + 1] = "2".into();
    args.extend(eval.map(String::from));
    let learner = hosts.mpo(true, &strs(&args));
    let plants: Vec<Proc> = (0..2)
        .map(|i| {
            let mut p = plant_args(&listen, run);
            let k = p.iter().position(|a| a == "--index").unwrap();
            p[k + 1] = i.to_string();
            // Paced (400 steps/s each): the second half lasts seconds, time enough to kill.
            p.extend(["--rate".into(), "400".into()]);
            hosts.mpo(false, &strs(&p))
        })
        .collect();
    let meta = out.join("checkpoint/meta.json");
    let t0 = Instant::now();
    loop {
        let steps = std::fs::read(&meta)
            .ok()
            .and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok())
            .and_then(|m| m["env_steps"].as_u64());
        if steps == Some(2000) {
            break;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(120),
            "no checkpoint at 2000 steps:\n{}",
            learner.log()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    // SIGKILL: no STOP reaches the plants; they wait for their learner's resumed self.
    drop(learner);
    let mut resume: Vec<String> = ["train", "--no-progress", "--steps", "4000", "--resume"]
        .map(String::from)
        .to_vec();
    resume.push(out.to_str().unwrap().into());
    resume.extend(
        [
            "--plants-remote",
            "2",
            "--fleet-listen",
            &listen,
            "--sync-every",
            "10",
            "--plant-timeout",
            "60",
        ]
        .map(String::from),
    );
    let (st, stdout, log) = hosts.mpo(true, &strs(&resume)).finish();
    let mut plogs = String::new();
    for p in plants {
        let (pst, _, plog) = p.finish();
        assert!(pst.success(), "plant {pst}:\n{plog}\nlearner:\n{log}");
        assert!(
            plog.contains("another incarnation of the run's learner speaks; joining again"),
            "{plog}"
        );
        plogs.push_str(&plog);
    }
    assert!(
        st.success(),
        "resumed learner {st}:\n{log}\nplants:\n{plogs}"
    );
    let s: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
    assert_eq!(s["env_steps"], 4000, "{log}");
    assert_eq!(s["fleet"]["rejoined"], 2, "{log}");
    let mut local_args = vec!["--plants", "2", "--sync-every", "10"];
    local_args.extend(eval);
    let local = ok_json(&tiny(&dir.join("iceoryx2"), 4000, &local_args));
    assert_eq!(sha(&s), sha(&local), "{s}\n{local}");
}
