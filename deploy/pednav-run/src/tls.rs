//! Mutual TLS between the hosts of a run, as `pednav-run` takes it: the three
//! `--tls-*` flags of `launch`, `join` and the bridge process, checked together and
//! handed on from the launcher to its bridge.
//!
//! Invariant: either all three files are given or none (clap refuses the rest), and
//! the paths handed on are absolute, so the bridge reads the files the user named
//! whatever its working directory.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;
use pednav_bridge::TlsFiles;

/// Mutual TLS between the hosts of a run: all three files or none.
#[derive(Args, Debug, Clone, Default)]
pub struct TlsArgs {
    /// The CA certificate (PEM) that signed every host's certificate. With the three
    /// --tls-* files the link is mutual TLS (endpoints `tls/HOST:PORT`): only hosts
    /// holding a certificate of this CA take part (docs/multi-host.md, *TLS*).
    #[arg(long, value_name = "PEM", requires_all = ["tls_cert", "tls_key"])]
    tls_ca: Option<PathBuf>,
    /// This host's certificate (PEM), signed by --tls-ca; the learner host's must name
    /// the host (DNS name or IP address) that actor hosts give to --connect.
    #[arg(long, value_name = "PEM", requires_all = ["tls_ca", "tls_key"])]
    tls_cert: Option<PathBuf>,
    /// This host's private key (PEM: PKCS#8, SEC1 or PKCS#1).
    #[arg(long, value_name = "PEM", requires_all = ["tls_ca", "tls_cert"])]
    tls_key: Option<PathBuf>,
}

impl TlsArgs {
    /// Whether the files were given (the link is then mutual TLS).
    pub fn given(&self) -> bool {
        self.tls_ca.is_some()
    }

    /// The files, as absolute paths (the bridge process gets them too), if given.
    pub fn files(&self) -> Result<Option<TlsFiles>> {
        let (Some(ca), Some(certificate), Some(key)) = (&self.tls_ca, &self.tls_cert, &self.tls_key) else {
            return Ok(None);
        };
        let absolute = |p: &PathBuf| std::path::absolute(p).with_context(|| format!("the path {}", p.display()));
        Ok(Some(TlsFiles { ca: absolute(ca)?, certificate: absolute(certificate)?, key: absolute(key)? }))
    }
}

/// The flags that hand TLS files on to a bridge process.
pub fn tls_flags(tls: Option<&TlsFiles>) -> Vec<String> {
    tls.map_or_else(Vec::new, |t| {
        let path = |p: &PathBuf| p.display().to_string();
        vec![
            "--tls-ca".into(),
            path(&t.ca),
            "--tls-cert".into(),
            path(&t.certificate),
            "--tls-key".into(),
            path(&t.key),
        ]
    })
}
