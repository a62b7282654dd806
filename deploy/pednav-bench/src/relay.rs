//! A TCP relay on loopback between two hosts of a run on one machine, so that a bench
//! or a soak can cut the link between them: it forwards every connection made to its
//! port to the target port, and [`Relay::cut_later`] closes every relayed connection
//! and refuses new ones for a while — to both ends, a link that went away.
//!
//! Invariant: it binds and connects on 127.0.0.1 only.

use std::io::{Read, Write};
use std::net::{Shutdown, TcpListener, TcpStream};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};

/// A free TCP port on loopback (bound, then released for the caller to take).
pub fn free_port() -> Result<u16> {
    Ok(TcpListener::bind("127.0.0.1:0")?.local_addr()?.port())
}

/// The relay (see the module doc); it runs until the process ends.
pub struct Relay {
    open: Arc<Mutex<Vec<TcpStream>>>,
    refuse_until: Arc<Mutex<Option<Instant>>>,
}

impl Relay {
    /// Forward connections to 127.0.0.1:`port` to 127.0.0.1:`target`.
    pub fn start(port: u16, target: u16) -> Result<Relay> {
        let listener = TcpListener::bind(("127.0.0.1", port)).with_context(|| format!("relay port {port}"))?;
        let relay = Relay { open: Arc::default(), refuse_until: Arc::default() };
        let (open, refuse) = (relay.open.clone(), relay.refuse_until.clone());
        std::thread::spawn(move || {
            for inbound in listener.incoming().flatten() {
                if refuse.lock().unwrap().is_some_and(|t| Instant::now() < t) {
                    let _ = inbound.shutdown(Shutdown::Both);
                    continue;
                }
                let Ok(outbound) = TcpStream::connect(("127.0.0.1", target)) else { continue };
                let _ = (inbound.set_nodelay(true), outbound.set_nodelay(true));
                for (from, to) in [(&inbound, &outbound), (&outbound, &inbound)] {
                    let (Ok(mut from), Ok(mut to)) = (from.try_clone(), to.try_clone()) else { continue };
                    std::thread::spawn(move || {
                        let mut buf = vec![0u8; 1 << 16];
                        while let Ok(n) = from.read(&mut buf) {
                            if n == 0 || to.write_all(&buf[..n]).is_err() {
                                break;
                            }
                        }
                        let _ = (from.shutdown(Shutdown::Both), to.shutdown(Shutdown::Both));
                    });
                }
                // Kept for a cut (a link reconnects a handful of times in a run, so the
                // list stays short).
                open.lock().unwrap().extend([inbound, outbound]);
            }
        });
        Ok(relay)
    }

    /// After `after`, close every relayed connection and refuse new ones for `down`.
    pub fn cut_later(&self, after: Duration, down: Duration) {
        let (open, refuse) = (self.open.clone(), self.refuse_until.clone());
        std::thread::spawn(move || {
            std::thread::sleep(after);
            *refuse.lock().unwrap() = Some(Instant::now() + down);
            for s in open.lock().unwrap().drain(..) {
                let _ = s.shutdown(Shutdown::Both);
            }
            eprintln!("link cut for {:.1} s", down.as_secs_f64());
        });
    }
}
