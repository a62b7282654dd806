//! A run across two hosts on one machine: a learner host with no actors of its own
//! (`pednav-run launch --actors 0 --listen tcp/127.0.0.1:PORT`) and an actor host with
//! one actor (`pednav-run join --connect …`), each with its own run directory (so its
//! own iceoryx2 services), joined over zenoh on loopback only.
//!
//! Checks: the join gives the actor host the run's config and actor id 0; training
//! runs on the remote actor's records; the learner's weights reach the remote actor and
//! are used; its tasks come from the learner host's curriculum service; the actor
//! host's bridge killed with SIGKILL mid-run is restarted by its launcher and the step
//! stream stays whole — every record the actor sent reached the learner once, in order,
//! with its checksum, from the first — and every episode report the actor made reaches
//! the curriculum service exactly once (its actor holds it until the curriculum
//! service acknowledges it, so the killed bridge loses none).
//! Bad endpoints and unreachable hosts are refused
//! naming what to fix. The same two hosts train over mutual TLS with the test
//! certificates, and across two network namespaces the test makes (a routed link
//! between two addresses, not loopback), where the link is cut for 15 s mid-run and
//! comes back: the stream and the episode reports stay whole. The bridge benchmark over mutual TLS (both
//! directions loaded) keeps its link and loses nothing. Only watchdogs — no timing
//! assertions.

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use pednav_runtime::stats::{ActorStats, BridgeStats};
use pednav_tests::run::{actor, bin_dir, curriculum, learner, stats, stop, wait_for, wait_within};
use pednav_tests::{scratch_dir, workspace_root};

/// A free TCP port on loopback (bound, then released for the learner host to take).
fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

/// A launcher that is killed when the test ends, passing or failing (its children get
/// SIGTERM when it dies), so a failed test leaves no run behind.
struct Launcher(Child);

impl Drop for Launcher {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// `pednav-run ARGS`, its output to `log`.
fn pednav_run(args: &[&str], log: &Path) -> Launcher {
    pednav_run_in(None, args, log)
}

/// `pednav-run ARGS` in the network namespace `netns` (`ip netns exec` switches
/// namespace and then executes the launcher in its own place, so the child is the
/// launcher), or in this one.
fn pednav_run_in(netns: Option<&str>, args: &[&str], log: &Path) -> Launcher {
    let launcher = bin_dir().join("pednav-run");
    let mut command = match netns {
        Some(ns) => {
            let mut c = Command::new("ip");
            c.args(["netns", "exec", ns]).arg(&launcher);
            c
        }
        None => Command::new(&launcher),
    };
    Launcher(
        command
            .args(args)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(log).unwrap())
            .spawn()
            .expect("start pednav-run"),
    )
}

/// The pid of the running process whose command line holds every one of `args`.
fn pid_with(args: &[&str]) -> Option<i32> {
    std::fs::read_dir("/proc").ok()?.flatten().find_map(|e| {
        let pid: i32 = e.file_name().to_str()?.parse().ok()?;
        let cmdline = std::fs::read(e.path().join("cmdline")).ok()?;
        let have: Vec<String> = cmdline.split(|&b| b == 0).map(|a| String::from_utf8_lossy(a).into_owned()).collect();
        args.iter().all(|a| have.iter().any(|h| h == a)).then_some(pid)
    })
}

/// The bridge's stats file of a run directory (`None` until it exists).
fn bridge_stats(run_dir: &Path) -> Option<BridgeStats> {
    stats(run_dir, "bridge")
}

/// The records the learner has taken of every stream (its stats file).
fn records_taken(learner_dir: &Path) -> Option<u64> {
    learner(learner_dir).map(|l| l.streams.iter().map(|s| s.records).sum())
}

/// Stop the actor host (the learner host takes what is on its way) and check that its
/// one actor's stream reached the learner whole: every record once, in order, from
/// the first, with its checksum, without a jump; and that the actor heard every one of
/// its episode reports acknowledged, none given up. The actor's final stats.
fn stop_actor_host_and_check_stream(actor_host: &mut Launcher, actor_dir: &Path, learner_dir: &Path) -> ActorStats {
    stop(&mut actor_host.0, actor_dir);
    let sent = actor(actor_dir, "actor-0.1").expect("the remote actor's final stats");
    let whole =
        wait_within(learner_dir, "the learner taking the remote stream to its end", Duration::from_secs(120), || {
            let l = learner(learner_dir)?;
            let t = l.streams.iter().find(|s| s.actor == 0 && s.incarnation == 1)?.clone();
            (t.records == sent.steps_sent).then_some(t)
        });
    assert_eq!(whole.first_seq, Some(0), "the stream reached the learner from its first record");
    assert_eq!(whole.checksum, sent.checksum, "every record arrived bit for bit");
    assert_eq!(whole.resumed, 0, "nothing was jumped over: {whole:?}");
    assert_eq!((sent.reports_unacknowledged, sent.reports_given_up), (0, 0), "every report acknowledged: {sent:?}");
    sent
}

/// Every episode report the remote actor made was taken by the learner host's
/// curriculum service exactly once (read after the learner host stopped).
fn check_reports_taken_once(learner_dir: &Path, sent: &ActorStats) {
    let c = curriculum(learner_dir).expect("the curriculum service's stats");
    assert!(sent.episodes > 0, "the remote actor finished episodes: {sent:?}");
    assert_eq!(c.episodes, sent.episodes, "reports taken by the curriculum service vs made by the actor: {c:?}");
}

/// Two hosts of one run on this machine, each with its run directory (and its log
/// beside it) under the scratch folder `name`: a learner host with no actors listening on `scheme/127.0.0.1:PORT`, and an
/// actor host `actors-1` with one actor joined to it; with `tls`, both give the test
/// certificates' flags.
struct TwoHosts {
    learner_dir: std::path::PathBuf,
    actor_dir: std::path::PathBuf,
    learner_host: Launcher,
    actor_host: Launcher,
}

fn two_hosts(name: &str, tls: bool) -> TwoHosts {
    let root = scratch_dir(name);
    let (learner_dir, actor_dir) = (root.join("learner-host"), root.join("actor-host"));
    let endpoint = format!("{}/127.0.0.1:{}", if tls { "tls" } else { "tcp" }, free_port());
    let config = workspace_root().join("deploy/configs/smoke.toml");
    let (ld, ad) = (learner_dir.to_str().unwrap(), actor_dir.to_str().unwrap());
    let with_tls = |base: &[&str], host: &str| -> Vec<String> {
        let extra = if tls { tls_flags(host) } else { Vec::new() };
        base.iter().map(|a| a.to_string()).chain(extra).collect()
    };
    let learner_args = with_tls(
        &["launch", "--config", config.to_str().unwrap(), "--run-dir", ld, "--actors", "0", "--listen", &endpoint],
        "learner-host",
    );
    let actor_args = with_tls(
        &["join", "--connect", &endpoint, "--actors", "1", "--run-dir", ad, "--host", "actors-1"],
        "actor-host",
    );
    fn strs(v: &[String]) -> Vec<&str> {
        v.iter().map(String::as_str).collect()
    }
    let learner_host = pednav_run(&strs(&learner_args), &root.join("learner-host.log"));
    let actor_host = pednav_run(&strs(&actor_args), &root.join("actor-host.log"));
    TwoHosts { learner_dir, actor_dir, learner_host, actor_host }
}

#[test]
fn a_learner_host_and_an_actor_host_train_over_loopback() {
    let TwoHosts { learner_dir, actor_dir, mut learner_host, mut actor_host } = two_hosts("multihost", false);
    let ad = actor_dir.to_str().unwrap();

    // The join recorded the learner host's config; the remote actor trains with its weights.
    let acting = wait_for(&actor_dir, "the remote actor acting with weights from the learner host", || {
        let live = actor(&actor_dir, "actor-0.live")?;
        (live.last_policy_version? >= 10).then_some(live)
    });
    assert_eq!(
        std::fs::read_to_string(actor_dir.join("config.toml")).unwrap(),
        std::fs::read_to_string(learner_dir.join("config.toml")).unwrap(),
        "the actor host runs the learner host's config"
    );
    let hosts = std::fs::read_to_string(learner_dir.join("hosts.json")).unwrap();
    assert!(hosts.contains("actors-1"), "the learner host recorded the join: {hosts}");
    assert!(acting.tasks_received >= 1, "tasks came across the link: {acting:?}");

    // SIGKILL the actor host's bridge: its launcher restarts it, and the stream goes on.
    let bridge = pid_with(&["bridge", ad]).expect("the actor host's bridge runs");
    // SAFETY: the pid is the bridge process the actor host's launcher started.
    unsafe { libc::kill(bridge, libc::SIGKILL) };
    wait_for(&actor_dir, "the actor host's launcher restarting its bridge", || {
        pid_with(&["bridge", ad]).filter(|p| *p != bridge)
    });
    // The learner's stats file lags by up to a second: once it shows everything the dead
    // bridge delivered, growth can only come through the new one.
    std::thread::sleep(Duration::from_secs(3));
    let before = records_taken(&learner_dir).expect("learner stats");
    wait_for(&learner_dir, "remote records arriving again through the new bridge", || {
        (records_taken(&learner_dir)? > before + 300).then_some(())
    });

    // Records the killed bridge held were missed and sent again (counted as out of order
    // or duplicates on arrival, never taken twice); nothing was jumped over.
    let sent = stop_actor_host_and_check_stream(&mut actor_host, &actor_dir, &learner_dir);
    stop(&mut learner_host.0, &learner_dir);

    let l = learner(&learner_dir).unwrap();
    let used = sent.last_policy_version.unwrap_or(0);
    assert!(used > 0 && used <= l.updates, "the remote actor used version {used} of {} updates", l.updates);
    let (lb, ab) = (bridge_stats(&learner_dir).unwrap(), bridge_stats(&actor_dir).unwrap());
    assert!(lb.step_records >= sent.steps_sent, "{lb:?}");
    assert!(lb.tasks >= 1 && lb.heartbeats >= 1, "{lb:?}");
    assert!(ab.weights >= 1 && ab.ack_tables >= 1, "{ab:?}");
    assert_eq!((lb.refused, ab.refused), (0, 0), "{lb:?} {ab:?}");
    // The actor held its episode reports until the curriculum service acknowledged
    // them: the killed bridge lost none, and the curriculum took each once.
    check_reports_taken_once(&learner_dir, &sent);
    assert!(ab.report_acks >= 1 && lb.episode_reports >= 1, "{lb:?} {ab:?}");
}

#[test]
fn bad_endpoints_and_unreachable_learner_hosts_are_refused_naming_the_fix() {
    let root = scratch_dir("multihost-refusals");
    let run_dir = root.join("run");
    let rd = run_dir.to_str().unwrap();
    let config = workspace_root().join("deploy/configs/smoke.toml");
    let refused = |args: &[&str]| {
        let out = Command::new(bin_dir().join("pednav-run")).args(args).output().unwrap();
        assert!(!out.status.success(), "{args:?} was accepted");
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    let cfg = config.to_str().unwrap();
    let no_actors = refused(&["launch", "--config", cfg, "--run-dir", rd, "--actors", "0"]);
    assert!(no_actors.contains("--actors") && no_actors.contains("--listen"), "{no_actors}");
    let udp = refused(&["launch", "--config", cfg, "--run-dir", rd, "--listen", "udp/127.0.0.1:7447"]);
    assert!(udp.contains("--listen udp/127.0.0.1:7447") && udp.contains("tcp/HOST:PORT"), "{udp}");
    // A port another learner host (here: this test) holds stops the launch before it starts anything.
    let held = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let taken = format!("tcp/127.0.0.1:{}", held.local_addr().unwrap().port());
    let busy = refused(&["launch", "--config", cfg, "--run-dir", rd, "--actors", "0", "--listen", &taken]);
    assert!(busy.contains(&format!("--listen {taken}")) && busy.contains("another learner host"), "{busy}");
    drop(held);
    let multicast = refused(&["join", "--connect", "tcp/224.0.0.224:7446", "--run-dir", rd]);
    assert!(multicast.contains("multicast"), "{multicast}");
    // Nothing listens on this port: the join fails within its timeout, saying what to check.
    let nobody = format!("tcp/127.0.0.1:{}", free_port());
    let unreachable = refused(&["join", "--connect", &nobody, "--run-dir", rd]);
    assert!(unreachable.contains("--listen"), "{unreachable}");
    // TLS: the files without a tls/ endpoint, a tls/ endpoint without the files.
    let tls = tls_flags("learner-host");
    let tls: Vec<&str> = tls.iter().map(String::as_str).collect();
    let no_listen = refused(&[&["launch", "--config", cfg, "--run-dir", rd][..], &tls[..]].concat());
    assert!(no_listen.contains("--listen tls/HOST:PORT"), "{no_listen}");
    let plain = refused(
        &[&["launch", "--config", cfg, "--run-dir", rd, "--listen", "tcp/127.0.0.1:7447"][..], &tls[..]].concat(),
    );
    assert!(plain.contains("use tls/HOST:PORT"), "{plain}");
    let no_files = refused(&["join", "--connect", "tls/127.0.0.1:7447", "--run-dir", rd]);
    assert!(no_files.contains("--tls-ca"), "{no_files}");
    assert!(!run_dir.join("config.toml").exists(), "a refused join starts nothing");
}

/// The test certificates' flags for `host` (`shared/bridge/testdata/tls`).
fn tls_flags(host: &str) -> Vec<String> {
    let dir = workspace_root().join("shared/bridge/testdata/tls");
    let file = |name: String| dir.join(name).to_str().unwrap().to_string();
    vec![
        "--tls-ca".into(),
        file("ca.pem".into()),
        "--tls-cert".into(),
        file(format!("{host}.pem")),
        "--tls-key".into(),
        file(format!("{host}.key")),
    ]
}

/// The same two hosts over mutual TLS (`tls/` endpoints, the test CA's certificates):
/// the join, the weights and the tasks cross, and the remote actor trains.
#[test]
fn a_learner_host_and_an_actor_host_train_over_mutual_tls() {
    let TwoHosts { learner_dir, actor_dir, mut learner_host, mut actor_host } = two_hosts("multihost-tls", true);
    let ad = actor_dir.to_str().unwrap();

    let acting = wait_for(&actor_dir, "the remote actor acting with weights from the learner host over TLS", || {
        let live = actor(&actor_dir, "actor-0.live")?;
        (live.last_policy_version? >= 3).then_some(live)
    });
    assert!(acting.tasks_received >= 1, "tasks came across the TLS link: {acting:?}");
    // The bridges were started with the TLS files (the launcher hands them on).
    assert!(pid_with(&["bridge", ad, "--tls-cert"]).is_some(), "the actor host's bridge runs with TLS");
    stop(&mut actor_host.0, &actor_dir);
    stop(&mut learner_host.0, &learner_dir);
    let (lb, ab) = (bridge_stats(&learner_dir).unwrap(), bridge_stats(&actor_dir).unwrap());
    assert!(lb.step_records > 0 && ab.weights >= 1, "{lb:?} {ab:?}");
    assert_eq!((lb.refused, ab.refused), (0, 0), "{lb:?} {ab:?}");
    // The link stayed up until the actor host stopped: zenoh's TLS link drops under
    // two-way traffic unless its reads and writes share a thread
    // (`pednav_bridge::link::TLS_SAFE_RUNTIME`).
    assert_eq!(lb.hosts_gone, 1, "the actor host left the TLS link only when it stopped: {lb:?}");
}

/// The bridge benchmark over mutual TLS — step records one way as fast as the link
/// takes them; acknowledgements, heartbeats, weights and tasks the other way — keeps
/// its link up and loses nothing. zenoh 1.10's TLS link fails under exactly this load
/// unless its reads and writes run on one thread, which `pednav-run` arranges for
/// itself (`pednav_bridge::link::TLS_SAFE_RUNTIME`); without it links drop and come
/// back over and over and the throughput phase never ends (docs/multi-host.md, *TLS*).
#[test]
fn the_bridge_benchmark_over_mutual_tls_keeps_its_link_and_loses_nothing() {
    let dir = scratch_dir("multihost-tls-bench");
    let (json, log) = (dir.join("bridge.json"), dir.join("bench.log"));
    let tls_dir = workspace_root().join("shared/bridge/testdata/tls");
    let args = [
        "bench",
        "bridge",
        "--tls-dir",
        tls_dir.to_str().unwrap(),
        "--records",
        "20000",
        "--repeats",
        "20",
        "--drop-secs",
        "0",
        "--stall-secs",
        "0",
        "--json",
        json.to_str().unwrap(),
    ];
    let mut bench = pednav_run(&args, &log);
    // ≈ 40 s with the link up (the fault phase sends for 22 s); the watchdog bounds a
    // link that keeps dropping.
    let start = std::time::Instant::now();
    let status = loop {
        if let Some(status) = bench.0.try_wait().unwrap() {
            break status;
        }
        let tail = || std::fs::read_to_string(&log).unwrap_or_default();
        assert!(
            start.elapsed() < Duration::from_secs(240),
            "the TLS bridge bench did not finish in 240 s:\n{}",
            tail()
        );
        std::thread::sleep(Duration::from_millis(200));
    };
    let text = std::fs::read_to_string(&log).unwrap_or_default();
    assert!(status.success(), "bench bridge failed ({status}):\n{text}");
    assert!(text.contains("ZENOH_RUNTIME"), "the launcher says which zenoh runtime layout it set:\n{text}");
    let figures: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(figures["transport"], "tls", "{figures}");
    for key in ["lost", "duplicated", "corrupted", "transport_closed"] {
        assert_eq!(figures[key].as_u64(), Some(0), "{key}: {figures}");
    }
    assert!(figures["fault_records_sent"].as_u64().unwrap() > 0, "{figures}");
}

/// Two network namespaces made for one test and joined by a veth pair: `learner`
/// holds [`LEARNER_ADDRESS`]/30, `actors` 10.213.0.2/30, each with its own loopback
/// up. Nothing routes out of them, so what the hosts send stays inside the pair. Both
/// (with the pair) are deleted when the value is dropped.
struct Namespaces {
    learner: String,
    actors: String,
    /// The actor side's end of the pair: taken down to cut the link.
    actors_end: String,
}

/// The learner host's address inside its namespace.
const LEARNER_ADDRESS: &str = "10.213.0.1";

/// `ip ARGS`, or what it said when it failed.
fn ip(args: &[&str]) -> Result<(), String> {
    let out = Command::new("ip").args(args).output().map_err(|e| format!("`ip` (iproute2) did not run: {e}"))?;
    if out.status.success() {
        Ok(())
    } else {
        Err(format!("`ip {}` failed: {}", args.join(" "), String::from_utf8_lossy(&out.stderr).trim()))
    }
}

impl Namespaces {
    /// The pair, or why this machine cannot make it (namespaces need root or
    /// CAP_SYS_ADMIN, and `ip` from iproute2).
    fn create() -> Result<Namespaces, String> {
        let id = std::process::id();
        let ns = Namespaces {
            learner: format!("pednav-{id}-learner"),
            actors: format!("pednav-{id}-actors"),
            actors_end: format!("pnv{id}a"),
        };
        let learner_end = format!("pnv{id}l");
        for netns in [&ns.learner, &ns.actors] {
            // A namespace a killed earlier test of the same pid left behind goes first.
            let _ = ip(&["netns", "del", netns]);
            ip(&["netns", "add", netns])?;
            // Some containers allow making a namespace but not entering it.
            ip(&["netns", "exec", netns, "true"])?;
        }
        // Made inside the learner's namespace, its peer straight inside the actors'.
        ip(&[
            "-n",
            &ns.learner,
            "link",
            "add",
            &learner_end,
            "type",
            "veth",
            "peer",
            "name",
            &ns.actors_end,
            "netns",
            &ns.actors,
        ])?;
        let learner_cidr = format!("{LEARNER_ADDRESS}/30");
        for (netns, end, cidr) in
            [(&ns.learner, &learner_end, learner_cidr.as_str()), (&ns.actors, &ns.actors_end, "10.213.0.2/30")]
        {
            ip(&["-n", netns, "addr", "add", cidr, "dev", end])?;
            ip(&["-n", netns, "link", "set", end, "up"])?;
            ip(&["-n", netns, "link", "set", "lo", "up"])?;
        }
        Ok(ns)
    }

    /// Take the actor side's end of the link down (`false`) or up again.
    fn link(&self, up: bool) {
        let state = if up { "up" } else { "down" };
        ip(&["-n", &self.actors, "link", "set", &self.actors_end, state]).unwrap();
    }
}

impl Drop for Namespaces {
    fn drop(&mut self) {
        // Deleting a namespace deletes the veth end inside it, and so the pair.
        for ns in [&self.learner, &self.actors] {
            let _ = ip(&["netns", "del", ns]);
        }
    }
}

/// A learner host and an actor host in two network namespaces of their own, joined
/// over a routed veth link (not loopback): the join, the weights and the tasks cross;
/// then the link is cut for 15 s — longer than zenoh's 10 s lease, so both sides see
/// the other leave — and comes back: the actor host reconnects, its actor's stream
/// goes on, and at the end every record it sent reached the learner once, in order,
/// with its checksum, and no episode report reached the curriculum twice.
///
/// Needs root (or CAP_SYS_ADMIN) and `ip`; where this machine cannot make network
/// namespaces the test says so on stderr and passes without running, unless
/// `PEDNAV_REQUIRE_NETNS=1` makes that a failure.
#[test]
fn hosts_in_two_network_namespaces_train_across_a_link_that_drops_and_comes_back() {
    let ns = match Namespaces::create() {
        Ok(ns) => ns,
        Err(why) if std::env::var("PEDNAV_REQUIRE_NETNS").as_deref() != Ok("1") => {
            eprintln!("SKIPPED: this machine cannot make network namespaces for the test: {why}");
            return;
        }
        Err(why) => panic!("PEDNAV_REQUIRE_NETNS=1 and no network namespaces: {why}"),
    };
    let root = scratch_dir("multihost-netns");
    let (learner_dir, actor_dir) = (root.join("learner-host"), root.join("actor-host"));
    let (ld, ad) = (learner_dir.to_str().unwrap(), actor_dir.to_str().unwrap());
    // A fresh namespace has every port free.
    let endpoint = format!("tcp/{LEARNER_ADDRESS}:7447");
    let config = workspace_root().join("deploy/configs/smoke.toml");
    let mut learner_host = pednav_run_in(
        Some(&ns.learner),
        &["launch", "--config", config.to_str().unwrap(), "--run-dir", ld, "--actors", "0", "--listen", &endpoint],
        &root.join("learner-host.log"),
    );
    let mut actor_host = pednav_run_in(
        Some(&ns.actors),
        &["join", "--connect", &endpoint, "--actors", "1", "--run-dir", ad, "--host", "actors-1"],
        &root.join("actor-host.log"),
    );

    let acting = wait_for(&actor_dir, "the remote actor acting with weights from the other namespace", || {
        let live = actor(&actor_dir, "actor-0.live")?;
        (live.last_policy_version? >= 3).then_some(live)
    });
    assert!(acting.tasks_received >= 1, "tasks came across the link: {acting:?}");

    // Cut the link for longer than the lease, then bring it back.
    ns.link(false);
    std::thread::sleep(Duration::from_secs(15));
    ns.link(true);
    wait_for(&learner_dir, "the learner host seeing the actor host leave during the cut", || {
        (bridge_stats(&learner_dir)?.hosts_gone >= 1).then_some(())
    });
    let after_cut = records_taken(&learner_dir).expect("learner stats");
    wait_for(&learner_dir, "remote records arriving again after the link came back", || {
        (records_taken(&learner_dir)? > after_cut + 300).then_some(())
    });

    let sent = stop_actor_host_and_check_stream(&mut actor_host, &actor_dir, &learner_dir);
    stop(&mut learner_host.0, &learner_dir);

    let (lb, ab) = (bridge_stats(&learner_dir).unwrap(), bridge_stats(&actor_dir).unwrap());
    assert!(lb.step_records >= sent.steps_sent, "{lb:?}");
    assert_eq!((lb.refused, ab.refused), (0, 0), "{lb:?} {ab:?}");
    // The actor held its episode reports through the cut and sent them again; the
    // curriculum service took each once.
    check_reports_taken_once(&learner_dir, &sent);
}
