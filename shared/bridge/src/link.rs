//! Links between hosts: zenoh sessions that reach only the endpoints they are given,
//! and the key names a run's messages travel under.
//!
//! Invariants:
//! - a session opened here never scouts: multicast and gossip scouting are off (they
//!   send to addresses nobody named); it listens only on its `listen` endpoints and
//!   connects only to its `connect` endpoints;
//! - every endpoint is checked before a session opens — `tcp/HOST:PORT`, no multicast
//!   address, no port 0 or unspecified address to connect to — and a refusal names the
//!   flag and the endpoint;
//! - every key lives under `pednav/<run>/`, so two runs sharing a network never see
//!   each other's messages.
//!
//! zenoh's reliable channel is reliable per hop: nothing is sent again after a session
//! drops, and a blocking message that cannot be queued for `wait_before_close` closes
//! the transport. Losslessness is therefore pednav's own (`pednav_runtime::reliable`):
//! a link only carries records; the sender's window and the receiver's
//! acknowledgements make the stream whole.

use std::net::IpAddr;

use zenoh::Wait;

use crate::error::{BridgeError, Result};

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
}

impl LinkConfig {
    /// A session that listens on `listen` (the learner host).
    pub fn listening(listen: &[String]) -> LinkConfig {
        LinkConfig { listen: listen.to_vec(), connect: Vec::new(), connect_timeout_ms: 10_000, fail_unreached: true }
    }

    /// A session that connects to `connect` (an actor host); opening it fails when
    /// the learner host is not reached within 10 s.
    pub fn connecting(connect: &[String]) -> LinkConfig {
        LinkConfig { listen: Vec::new(), connect: connect.to_vec(), connect_timeout_ms: 10_000, fail_unreached: true }
    }

    /// This link, but opening it waits at most `connect_timeout_ms` for the learner
    /// host and then returns, trying on in the background.
    #[must_use]
    pub fn keep_trying(mut self) -> LinkConfig {
        self.fail_unreached = false;
        self
    }

    /// Check every endpoint (see [`check_endpoint`]) and that there is at least one.
    pub fn check(&self) -> Result<()> {
        if self.listen.is_empty() && self.connect.is_empty() {
            return Err(BridgeError::Link("a link needs --listen or --connect endpoints".into()));
        }
        for e in &self.listen {
            check_endpoint("--listen", e)?;
        }
        for e in &self.connect {
            check_endpoint("--connect", e)?;
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
        for (key, value) in settings {
            c.insert_json5(key, &value)
                .map_err(|e| BridgeError::Link(format!("zenoh setting {key} = {value} refused: {e}")))?;
        }
        Ok(c)
    }

    /// Open the session.
    pub fn open(&self) -> Result<zenoh::Session> {
        let config = self.zenoh_config()?;
        zenoh::open(config).wait().map_err(|e| {
            BridgeError::Link(format!(
                "could not open the link (listen {:?}, connect {:?}): {e}{}",
                self.listen,
                self.connect,
                if self.connect.is_empty() {
                    " — is the port in use?"
                } else {
                    " — is `pednav-run launch --listen …` running there, and the port open?"
                }
            ))
        })
    }
}

/// Close a session, waiting until its links are down (a close that fails leaves
/// nothing to do: the peer sees the link go either way).
pub fn close(session: zenoh::Session) {
    if let Err(e) = session.close().wait() {
        tracing::debug!("closing the link: {e}");
    }
}

/// Check one endpoint given to `flag`: `tcp/HOST:PORT` with a port, and an address
/// that names one host (not multicast; not unspecified or port 0 for `--connect`).
pub fn check_endpoint(flag: &str, endpoint: &str) -> Result<()> {
    let refuse = |problem: &str| {
        Err(BridgeError::Endpoint { flag: flag.to_string(), endpoint: endpoint.to_string(), problem: problem.into() })
    };
    let Some(address) = endpoint.strip_prefix("tcp/") else {
        return refuse("use tcp/HOST:PORT (TCP is the one transport this build carries)");
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

        let (tx, rx) = mpsc::channel::<Vec<u8>>();
        let _steps = learner
            .declare_subscriber(keys.all_steps())
            .callback(move |s| {
                let _ = tx.send(s.payload().to_bytes().into_owned());
            })
            .wait()
            .unwrap();
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
        let header = StepHeader { actor: 3, incarnation: 1, seq: 41, base: 40, ..StepHeader::default() };
        let record = wire::encode_step(&header, &[7u8; 42]);
        let publisher = actor
            .declare_publisher(keys.steps(3))
            .congestion_control(zenoh::qos::CongestionControl::Block)
            .wait()
            .unwrap();
        // The subscription reaches the actor's session some time after it is declared:
        // send until one arrives (bounded).
        let deadline = Instant::now() + Duration::from_secs(20);
        let got = loop {
            publisher.put(record.clone()).wait().unwrap();
            if let Ok(bytes) = rx.recv_timeout(Duration::from_millis(100)) {
                break bytes;
            }
            assert!(Instant::now() < deadline, "no record crossed the link within 20 s");
        };
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
