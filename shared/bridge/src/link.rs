//! Links between hosts: zenoh sessions that reach only the endpoints they are given,
//! and the key names a run's messages travel under.
//!
//! Invariants:
//! - a session opened here never scouts: multicast and gossip scouting are off (they
//!   send to addresses nobody named); it listens only on its `listen` endpoints and
//!   connects only to its `connect` endpoints;
//! - every endpoint is checked before a session opens — `tcp/HOST:PORT` (or
//!   `tls/HOST:PORT` with [`TlsFiles`], and then only `tls/`), no multicast address,
//!   no port 0 or unspecified address to connect to — and a refusal names the flag and
//!   the endpoint;
//! - TLS is always mutual: each host presents a certificate signed by the run's CA and
//!   accepts only a peer whose certificate that CA signed; a connecting host also checks
//!   that the learner host's certificate names the host it connects to;
//! - every key lives under `pednav/<run>/`, so two runs sharing a network never see
//!   each other's messages.
//!
//! zenoh's reliable channel is reliable per hop: nothing is sent again after a session
//! drops, and a blocking message that cannot be queued for `wait_before_close` closes
//! the transport. Losslessness is therefore pednav's own (`pednav_runtime::reliable`):
//! a link only carries records; the sender's window and the receiver's
//! acknowledgements make the stream whole.

use std::net::IpAddr;
use std::path::PathBuf;

use zenoh::Wait;

use crate::error::{BridgeError, Result};

/// The files of a host's mutual TLS (PEM): every host of a run has a certificate
/// signed by the same CA.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TlsFiles {
    /// The CA certificate that signed every host's certificate (`--tls-ca`).
    pub ca: PathBuf,
    /// This host's certificate (`--tls-cert`); the learner host's must name the host
    /// (DNS name or IP address) that actor hosts connect to.
    pub certificate: PathBuf,
    /// This host's private key (`--tls-key`; PKCS#8, SEC1 or PKCS#1).
    pub key: PathBuf,
}

impl TlsFiles {
    /// Each file with the flag that names it.
    fn flagged(&self) -> [(&'static str, &PathBuf); 3] {
        [("--tls-ca", &self.ca), ("--tls-cert", &self.certificate), ("--tls-key", &self.key)]
    }
}

/// Where a host's session listens and what it connects to.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct LinkConfig {
    /// Endpoints to listen on (`tcp/0.0.0.0:7447`): the learner host's `--listen`.
    pub listen: Vec<String>,
    /// Endpoints to connect to (`tcp/LEARNER_HOST:7447`): an actor host's `--connect`.
    pub connect: Vec<String>,
    /// How long opening a session waits for its `connect` endpoints (milliseconds).
    pub connect_timeout_ms: u64,
    /// Whether opening fails when the `connect` endpoints are not reached in time
    /// (`join`, which must not start anything without a learner host), or returns and
    /// keeps trying in the background (a bridge, which waits out a learner host that
    /// restarts; zenoh reconnects a dropped link to its `connect` endpoints by itself).
    pub fail_unreached: bool,
    /// Mutual TLS (endpoints `tls/…`), or plain TCP (`None`, endpoints `tcp/…`).
    pub tls: Option<TlsFiles>,
}

impl LinkConfig {
    /// A session that listens on `listen` (the learner host).
    pub fn listening(listen: &[String]) -> LinkConfig {
        LinkConfig {
            listen: listen.to_vec(),
            connect: Vec::new(),
            connect_timeout_ms: 10_000,
            fail_unreached: true,
            tls: None,
        }
    }

    /// A session that connects to `connect` (an actor host); opening it fails when
    /// the learner host is not reached within 10 s.
    pub fn connecting(connect: &[String]) -> LinkConfig {
        LinkConfig {
            listen: Vec::new(),
            connect: connect.to_vec(),
            connect_timeout_ms: 10_000,
            fail_unreached: true,
            tls: None,
        }
    }

    /// This link, but opening it waits at most `connect_timeout_ms` for the learner
    /// host and then returns, trying on in the background.
    #[must_use]
    pub fn keep_trying(mut self) -> LinkConfig {
        self.fail_unreached = false;
        self
    }

    /// This link with mutual TLS (`Some`) or plain TCP.
    #[must_use]
    pub fn with_tls(mut self, tls: Option<TlsFiles>) -> LinkConfig {
        self.tls = tls;
        self
    }

    /// Check every endpoint (see [`check_endpoint`]), that there is at least one, that
    /// TLS files come with `tls/` endpoints and `tls/` endpoints with TLS files, and
    /// that each TLS file can be read.
    pub fn check(&self) -> Result<()> {
        if self.listen.is_empty() && self.connect.is_empty() {
            return Err(BridgeError::Link("a link needs --listen or --connect endpoints".into()));
        }
        let flagged = self.listen.iter().map(|e| ("--listen", e)).chain(self.connect.iter().map(|e| ("--connect", e)));
        for (flag, e) in flagged {
            check_endpoint(flag, e)?;
            let refuse = |problem: &str| {
                Err(BridgeError::Endpoint { flag: flag.to_string(), endpoint: e.clone(), problem: problem.into() })
            };
            match (&self.tls, e.starts_with("tls/")) {
                (None, true) => return refuse("a tls/ endpoint needs --tls-ca, --tls-cert and --tls-key"),
                (Some(_), false) => {
                    return refuse(
                        "with --tls-ca/--tls-cert/--tls-key use tls/HOST:PORT (tcp/ would carry the run unencrypted)",
                    );
                }
                _ => {}
            }
        }
        for (flag, path) in self.tls.iter().flat_map(TlsFiles::flagged) {
            if let Err(e) = std::fs::File::open(path) {
                return Err(BridgeError::Link(format!("{flag} {}: cannot be read ({e})", path.display())));
            }
        }
        Ok(())
    }

    /// The zenoh configuration: a peer that scouts nothing and uses exactly these
    /// endpoints; opening fails when a listen endpoint cannot be bound or the connect
    /// endpoints are not reached within `connect_timeout_ms`.
    pub fn zenoh_config(&self) -> Result<zenoh::Config> {
        self.check()?;
        let mut c = zenoh::Config::default();
        let quoted = |v: &[String]| format!("[{}]", v.iter().map(|e| format!("{e:?}")).collect::<Vec<_>>().join(","));
        let settings = [
            ("mode", "\"peer\"".to_string()),
            ("scouting/multicast/enabled", "false".to_string()),
            ("scouting/gossip/enabled", "false".to_string()),
            ("listen/endpoints", quoted(&self.listen)),
            ("listen/timeout_ms", "0".to_string()),
            ("listen/exit_on_failure", "true".to_string()),
            ("connect/endpoints", quoted(&self.connect)),
            ("connect/timeout_ms", self.connect_timeout_ms.to_string()),
            ("connect/exit_on_failure", self.fail_unreached.to_string()),
        ];
        let tls_settings = self.tls.iter().flat_map(|t| {
            let file = |p: &PathBuf| format!("{:?}", p.display().to_string());
            [
                ("transport/link/tls/root_ca_certificate", file(&t.ca)),
                ("transport/link/tls/listen_certificate", file(&t.certificate)),
                ("transport/link/tls/listen_private_key", file(&t.key)),
                ("transport/link/tls/connect_certificate", file(&t.certificate)),
                ("transport/link/tls/connect_private_key", file(&t.key)),
                ("transport/link/tls/enable_mtls", "true".to_string()),
                ("transport/link/tls/verify_name_on_connect", "true".to_string()),
            ]
        });
        for (key, value) in settings.into_iter().chain(tls_settings) {
            c.insert_json5(key, &value)
                .map_err(|e| BridgeError::Link(format!("zenoh setting {key} = {value} refused: {e}")))?;
        }
        Ok(c)
    }

    /// Open the session.
    pub fn open(&self) -> Result<zenoh::Session> {
        let config = self.zenoh_config()?;
        if self.tls.is_some() && !tls_runtime_is_safe() {
            tracing::warn!(
                "this process uses a tls/ link without {ZENOH_RUNTIME_ENV}='{TLS_SAFE_RUNTIME}': zenoh 1.10's TLS link \
                 fails under load in both directions (links drop and reconnect; nothing is lost, little moves). \
                 `pednav-run` sets it itself when the variable is unset; another layout must keep that part"
            );
        }
        zenoh::open(config).wait().map_err(|e| {
            BridgeError::Link(format!(
                "could not open the link (listen {:?}, connect {:?}): {e}{}",
                self.listen,
                self.connect,
                match (self.connect.is_empty(), self.tls.is_some()) {
                    (true, false) => " — is the port in use?",
                    (true, true) => " — is the port in use, and are --tls-cert and --tls-key a certificate and its key?",
                    (false, false) => " — is `pednav-run launch --listen …` running there, and the port open?",
                    (false, true) => {
                        " — is `pednav-run launch --listen tls/…` running there, and the port open? With TLS: were both \
                         hosts' certificates signed by the same --tls-ca, and does the learner host's name the host \
                         in --connect?"
                    }
                }
            ))
        })
    }
}

/// The environment variable zenoh reads its runtimes' layout from, once, when the
/// process first uses zenoh.
pub const ZENOH_RUNTIME_ENV: &str = "ZENOH_RUNTIME";

/// The runtime layout a process with a `tls/` link needs: zenoh's link reads handed
/// over to its single write thread.
///
/// zenoh 1.10's TLS link (`zenoh-link-tls`) keeps one rustls connection behind two
/// separate locks, one for reads and one for writes, while zenoh reads on its `rx`
/// threads and writes on its `tx` thread: both touch the connection at once, which
/// rustls does not allow (upstream eclipse-zenoh/zenoh#2557). A write that lands while
/// a read decrypts fails ("handshake not complete"), and zenoh closes the link. With
/// this layout reads and writes run on one thread and never overlap (measured:
/// docs/multi-host.md, *TLS*). Plain TCP shares nothing between its two directions
/// and keeps zenoh's default layout.
pub const TLS_SAFE_RUNTIME: &str = "(rx: (handover: tx))";

/// Start a process that may open zenoh links: give it (and the children it starts,
/// which inherit its environment) zenoh's runtime layout for TLS links when `uses_tls`
/// and the user set none ([`TLS_SAFE_RUNTIME`] says why), then start logging, and say
/// so in the log when the layout was set here.
///
/// Call it first thing in `main`, before any thread exists.
pub fn start_process(uses_tls: bool) {
    let set = uses_tls && std::env::var_os(ZENOH_RUNTIME_ENV).is_none();
    if set {
        // SAFETY: the binaries call this first in `main`, before they start logging,
        // zenoh, rayon or any child: the process has one thread, so nothing reads the
        // environment while it changes.
        unsafe { std::env::set_var(ZENOH_RUNTIME_ENV, TLS_SAFE_RUNTIME) };
    }
    pednav_runtime::init_logging();
    if set {
        tracing::info!(
            "TLS link: {ZENOH_RUNTIME_ENV}='{TLS_SAFE_RUNTIME}' (zenoh 1.10's TLS link needs its reads and writes on \
             one thread; docs/multi-host.md, TLS)"
        );
    }
}

/// Whether this process runs zenoh with a link's reads handed over to its write thread
/// (a user's own [`ZENOH_RUNTIME_ENV`] may say more, as long as it says that).
fn tls_runtime_is_safe() -> bool {
    std::env::var(ZENOH_RUNTIME_ENV).is_ok_and(|v| {
        let v: String = v.chars().filter(|c| !c.is_whitespace()).collect();
        v.contains("rx:(handover:tx)")
    })
}

/// Close a session, waiting until its links are down (a close that fails leaves
/// nothing to do: the peer sees the link go either way).
pub fn close(session: zenoh::Session) {
    if let Err(e) = session.close().wait() {
        tracing::debug!("closing the link: {e}");
    }
}

/// The `HOST:PORT` of a `tcp/` or `tls/` endpoint (`None` for any other protocol).
pub fn endpoint_address(endpoint: &str) -> Option<&str> {
    endpoint.strip_prefix("tcp/").or_else(|| endpoint.strip_prefix("tls/"))
}

/// Check one endpoint given to `flag`: `tcp/HOST:PORT` with a port, and an address
/// that names one host (not multicast; not unspecified or port 0 for `--connect`).
pub fn check_endpoint(flag: &str, endpoint: &str) -> Result<()> {
    let refuse = |problem: &str| {
        Err(BridgeError::Endpoint { flag: flag.to_string(), endpoint: endpoint.to_string(), problem: problem.into() })
    };
    let Some(address) = endpoint_address(endpoint) else {
        return refuse("use tcp/HOST:PORT, or tls/HOST:PORT with --tls-ca, --tls-cert and --tls-key");
    };
    if address.contains(['#', '?']) {
        return refuse("endpoint options (after '#' or '?') are not supported");
    }
    let Some((host, port)) = address.rsplit_once(':') else {
        return refuse("no port: use tcp/HOST:PORT");
    };
    let Ok(port) = port.parse::<u16>() else {
        return refuse("the port is not a number from 0 to 65535");
    };
    let host = host.strip_prefix('[').and_then(|h| h.strip_suffix(']')).unwrap_or(host);
    if host.is_empty() {
        return refuse("no host: use tcp/HOST:PORT");
    }
    let connecting = flag == "--connect";
    if connecting && port == 0 {
        return refuse("port 0 names no listener to connect to");
    }
    if let Ok(ip) = host.parse::<IpAddr>() {
        if ip.is_multicast() {
            return refuse("a multicast address: pednav links only name single hosts");
        }
        if connecting && ip.is_unspecified() {
            return refuse("an unspecified address (0.0.0.0, ::) names no host to connect to");
        }
    } else if !host.chars().all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '.') {
        return refuse("the host is neither an IP address nor a host name");
    }
    Ok(())
}

/// The keys one run's messages travel under (`pednav/<run>/…`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Keys {
    root: String,
}

impl Keys {
    /// The keys of the run named `run` (letters, digits, '-', '_', '.').
    pub fn new(run: &str) -> Result<Keys> {
        if run.is_empty() || !run.chars().all(|c| c.is_ascii_alphanumeric() || "-_.".contains(c)) {
            return Err(BridgeError::Link(format!(
                "run name {run:?}: use letters, digits, '-', '_' or '.' (it becomes part of the link's keys)"
            )));
        }
        Ok(Keys { root: format!("pednav/{run}") })
    }

    /// One actor's step records.
    pub fn steps(&self, actor: u32) -> String {
        format!("{}/steps/{actor}", self.root)
    }

    /// Every actor's step records.
    pub fn all_steps(&self) -> String {
        format!("{}/steps/*", self.root)
    }

    /// One actor's episode reports.
    pub fn episodes(&self, actor: u32) -> String {
        format!("{}/episodes/{actor}", self.root)
    }

    /// Every actor's episode reports.
    pub fn all_episodes(&self) -> String {
        format!("{}/episodes/*", self.root)
    }

    /// The learner's acknowledgements.
    pub fn acks(&self) -> String {
        format!("{}/acks", self.root)
    }

    /// The learner host's acknowledgements of episode reports.
    pub fn report_acks(&self) -> String {
        format!("{}/episode-acks", self.root)
    }

    /// The policy weights (published, and queryable for the newest).
    pub fn weights(&self) -> String {
        format!("{}/weights", self.root)
    }

    /// The curriculum's task request-response.
    pub fn tasks(&self) -> String {
        format!("{}/tasks", self.root)
    }

    /// The run's end, said by the learner host once its learner finished.
    pub fn done(&self) -> String {
        format!("{}/done", self.root)
    }

    /// The heartbeats of one host's processes.
    pub fn heartbeats(&self, host: &str) -> String {
        format!("{}/heartbeats/{host}", self.root)
    }

    /// Every host's heartbeats.
    pub fn all_heartbeats(&self) -> String {
        format!("{}/heartbeats/*", self.root)
    }

    /// One host's liveliness token.
    pub fn alive(&self, host: &str) -> String {
        format!("{}/hosts/{host}", self.root)
    }

    /// Every host's liveliness token.
    pub fn all_alive(&self) -> String {
        format!("{}/hosts/*", self.root)
    }

    /// The host name of a key under [`Keys::all_alive`] or [`Keys::all_heartbeats`],
    /// or the actor id (as text) of one under [`Keys::all_steps`].
    pub fn last_segment(key: &str) -> &str {
        key.rsplit('/').next().unwrap_or(key)
    }
}

#[cfg(test)]
mod tests {
    use std::sync::mpsc;
    use std::time::{Duration, Instant};

    use pednav_runtime::messages::StepHeader;
    use zenoh::sample::SampleKind;

    use super::*;
    use crate::wire;

    #[test]
    fn endpoints_are_refused_naming_the_flag_the_endpoint_and_why() {
        for ok in ["tcp/127.0.0.1:7447", "tcp/[::1]:7447", "tcp/learner-1.lab:7447"] {
            check_endpoint("--connect", ok).unwrap();
        }
        check_endpoint("--listen", "tcp/0.0.0.0:7447").unwrap();
        check_endpoint("--listen", "tcp/127.0.0.1:0").unwrap();
        for (flag, bad, why) in [
            ("--connect", "udp/127.0.0.1:7447", "tcp/HOST:PORT"),
            ("--connect", "tcp/127.0.0.1", "no port"),
            ("--connect", "tcp/127.0.0.1:70000", "port is not a number"),
            ("--connect", "tcp/224.0.0.224:7446", "multicast"),
            ("--listen", "tcp/[ff02::1]:7446", "multicast"),
            ("--connect", "tcp/0.0.0.0:7447", "unspecified"),
            ("--connect", "tcp/127.0.0.1:0", "port 0"),
            ("--connect", "tcp/127.0.0.1:7447#iface=eth0", "options"),
            ("--connect", "tcp/:7447", "no host"),
            ("--connect", "tcp/bad host:7447", "neither an IP address"),
        ] {
            let err = check_endpoint(flag, bad).unwrap_err().to_string();
            assert!(err.contains(flag) && err.contains(bad) && err.contains(why), "{bad}: {err}");
        }
        assert!(LinkConfig::default().check().unwrap_err().to_string().contains("--listen or --connect"));
    }

    #[test]
    fn the_zenoh_config_scouts_nothing_and_names_exactly_the_endpoints() {
        let link = LinkConfig::connecting(&["tcp/127.0.0.1:7447".into()]);
        let c = link.zenoh_config().unwrap();
        assert_eq!(c.get_json("scouting/multicast/enabled").unwrap(), "false");
        assert_eq!(c.get_json("scouting/gossip/enabled").unwrap(), "false");
        assert_eq!(c.get_json("mode").unwrap(), "\"peer\"");
        let connect = c.get_json("connect/endpoints").unwrap();
        assert!(connect.contains("tcp/127.0.0.1:7447"), "{connect}");
        let listen = c.get_json("listen/endpoints").unwrap();
        assert!(!listen.contains("tcp"), "{listen}");
    }

    #[test]
    fn keys_stay_under_the_run() {
        let k = Keys::new("big-run.2").unwrap();
        assert_eq!(k.steps(17), "pednav/big-run.2/steps/17");
        assert_eq!(Keys::last_segment(&k.alive("gpu-a")), "gpu-a");
        assert!(Keys::new("a/b").is_err() && Keys::new("").is_err() && Keys::new("x*").is_err());
    }

    /// A free TCP port on loopback (bound, then released for the session to take).
    fn free_port() -> u16 {
        std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
    }

    /// A step record put by `actor` until `learner` receives one (bounded by `within`):
    /// the subscription reaches the other session some time after it is declared.
    fn first_record(
        learner: &zenoh::Session,
        actor: &zenoh::Session,
        keys: &Keys,
        within: Duration,
    ) -> Option<Vec<u8>> {
        let (tx, rx) = mpsc::channel::<Vec<u8>>();
        let _steps = learner
            .declare_subscriber(keys.all_steps())
            .callback(move |s| {
                let _ = tx.send(s.payload().to_bytes().into_owned());
            })
            .wait()
            .unwrap();
        let header = StepHeader { actor: 3, incarnation: 1, seq: 41, base: 40, ..StepHeader::default() };
        let record = wire::encode_step(&header, &[7u8; 42]);
        let publisher = actor
            .declare_publisher(keys.steps(3))
            .congestion_control(zenoh::qos::CongestionControl::Block)
            .wait()
            .unwrap();
        let deadline = Instant::now() + within;
        while Instant::now() < deadline {
            publisher.put(record.clone()).wait().unwrap();
            if let Ok(bytes) = rx.recv_timeout(Duration::from_millis(100)) {
                return Some(bytes);
            }
        }
        None
    }

    /// The test certificates (`testdata/tls`, made by its `make.sh`): `host`'s
    /// certificate and key, and the CA that signed the two test hosts'.
    fn tls(host: &str) -> TlsFiles {
        let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("testdata/tls");
        TlsFiles {
            ca: dir.join("ca.pem"),
            certificate: dir.join(format!("{host}.pem")),
            key: dir.join(format!("{host}.key")),
        }
    }

    #[test]
    fn tls_endpoints_and_tls_files_come_together() {
        let err = LinkConfig::connecting(&["tls/127.0.0.1:7447".into()]).check().unwrap_err().to_string();
        assert!(err.contains("tls/127.0.0.1:7447") && err.contains("--tls-ca"), "{err}");
        let plain = LinkConfig::listening(&["tcp/0.0.0.0:7447".into()]).with_tls(Some(tls("learner-host")));
        let err = plain.check().unwrap_err().to_string();
        assert!(err.contains("--listen") && err.contains("use tls/HOST:PORT"), "{err}");
        let mut missing = tls("actor-host");
        missing.key = missing.key.with_file_name("no-such.key");
        let err = LinkConfig::connecting(&["tls/127.0.0.1:7447".into()]).with_tls(Some(missing)).check().unwrap_err();
        assert!(err.to_string().contains("--tls-key") && err.to_string().contains("no-such.key"), "{err}");

        let link = LinkConfig::connecting(&["tls/localhost:7447".into()]).with_tls(Some(tls("actor-host")));
        let c = link.zenoh_config().unwrap();
        assert_eq!(c.get_json("transport/link/tls/enable_mtls").unwrap(), "true");
        assert_eq!(c.get_json("transport/link/tls/verify_name_on_connect").unwrap(), "true");
        assert!(c.get_json("transport/link/tls/root_ca_certificate").unwrap().contains("ca.pem"));
        assert!(c.get_json("transport/link/tls/connect_private_key").unwrap().contains("actor-host.key"));
    }

    /// Mutual TLS on loopback: two hosts whose certificates the run's CA signed carry a
    /// record; a host with another CA's certificate gets nothing across, and an actor
    /// host refuses a "learner host" whose certificate the run's CA did not sign.
    #[test]
    fn a_tls_link_carries_records_between_the_runs_hosts_only() {
        let endpoint = format!("tls/127.0.0.1:{}", free_port());
        let learner = LinkConfig::listening(std::slice::from_ref(&endpoint)).with_tls(Some(tls("learner-host")));
        let learner = learner.open().unwrap();
        let actor = LinkConfig::connecting(std::slice::from_ref(&endpoint)).with_tls(Some(tls("actor-host")));
        let actor = actor.open().unwrap();
        let keys = Keys::new("tls-test").unwrap();
        let got =
            first_record(&learner, &actor, &keys, Duration::from_secs(20)).expect("a record crossed the TLS link");
        assert_eq!(wire::decode_step(&got).unwrap().0.seq, 41);
        actor.close().wait().unwrap();

        // A client certificate from another CA: the learner host refuses the handshake.
        let mut stranger = LinkConfig::connecting(std::slice::from_ref(&endpoint)).with_tls(Some(tls("stranger")));
        stranger.connect_timeout_ms = 3_000;
        match stranger.open() {
            Err(e) => assert!(e.to_string().contains("same --tls-ca"), "{e}"),
            Ok(session) => {
                let crossed = first_record(&learner, &session, &keys, Duration::from_secs(3));
                assert!(crossed.is_none(), "a host with another CA's certificate got a record across");
                session.close().wait().unwrap();
            }
        }
        learner.close().wait().unwrap();

        // A listener whose certificate another CA signed: the actor host refuses it.
        let endpoint = format!("tls/127.0.0.1:{}", free_port());
        // It trusts the run's CA but presents a certificate another CA signed.
        let impostor = LinkConfig::listening(std::slice::from_ref(&endpoint)).with_tls(Some(tls("stranger")));
        let impostor = impostor.open().unwrap();
        let mut actor = LinkConfig::connecting(std::slice::from_ref(&endpoint)).with_tls(Some(tls("actor-host")));
        actor.connect_timeout_ms = 3_000;
        let err = actor.open().map(|_| ()).unwrap_err().to_string();
        assert!(err.contains("could not open the link") && err.contains("same --tls-ca"), "{err}");
        impostor.close().wait().unwrap();
    }

    /// Two sessions on loopback — one listening, one connecting, nothing scouted —
    /// carry a step record, and a host's liveliness token disappears when its session
    /// closes. Loops are bounded in count and time.
    #[test]
    fn two_sessions_on_loopback_carry_a_record_and_see_a_host_go() {
        let port = free_port();
        let endpoint = format!("tcp/127.0.0.1:{port}");
        let learner = LinkConfig::listening(std::slice::from_ref(&endpoint)).open().unwrap();
        let actor = LinkConfig::connecting(&[endpoint]).open().unwrap();
        let keys = Keys::new("loopback-test").unwrap();

        let (alive_tx, alive_rx) = mpsc::channel::<(String, SampleKind)>();
        let _hosts = learner
            .liveliness()
            .declare_subscriber(keys.all_alive())
            .history(true)
            .callback(move |s| {
                let _ = alive_tx.send((Keys::last_segment(s.key_expr().as_str()).to_string(), s.kind()));
            })
            .wait()
            .unwrap();

        let _token = actor.liveliness().declare_token(keys.alive("gpu-a")).wait().unwrap();
        let got = first_record(&learner, &actor, &keys, Duration::from_secs(20)).expect("a record crossed the link");
        let (h, obs) = wire::decode_step(&got).unwrap();
        assert_eq!((h.actor, h.incarnation, h.seq, h.base), (3, 1, 41, 40));
        assert_eq!(obs, &[7u8; 42]);

        let seen = alive_rx.recv_timeout(Duration::from_secs(20)).expect("the host's token was seen");
        assert_eq!(seen, ("gpu-a".to_string(), SampleKind::Put));
        actor.close().wait().unwrap();
        let deadline = Instant::now() + Duration::from_secs(30);
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            assert!(!left.is_zero(), "the closed host's token was not withdrawn within 30 s");
            if let Ok((host, SampleKind::Delete)) = alive_rx.recv_timeout(left) {
                assert_eq!(host, "gpu-a");
                break;
            }
        }
        learner.close().wait().unwrap();
    }
}
