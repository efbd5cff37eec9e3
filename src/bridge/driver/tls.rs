//! The TLS client configuration of `mqtts://` connections: the broker's certificate is verified
//! against `ca_file` when one is configured, else against the system's trust store, the
//! certificates rustls-native-certs finds (`SSL_CERT_FILE` / `SSL_CERT_DIR` when set, else the
//! distribution's bundle such as `/etc/ssl/certs/ca-certificates.crt`); the client certificate
//! goes with it when one is configured. rustls with ring alone, chosen here explicitly rather
//! than through a process-wide default.

use std::path::Path;
use std::sync::Arc;

use anyhow::{bail, Context as _};
use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, PrivateKeyDer};
use rustls::{ClientConfig, RootCertStore};

use crate::config::TlsSettings;

/// The client configuration for `tls`: its trust anchors, and its client certificate if any.
pub fn client_config(tls: &TlsSettings) -> anyhow::Result<ClientConfig> {
    let roots = match &tls.ca_file {
        Some(ca_file) => ca_file_roots(ca_file)?,
        None => system_roots()?,
    };
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let builder = ClientConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .context("TLS protocol versions")?
        .with_root_certificates(roots);
    let config = match &tls.client_auth {
        Some((cert_file, key_file)) => {
            let chain = certificates(cert_file, "cert_file")?;
            let key = PrivateKeyDer::from_pem_file(key_file)
                .with_context(|| format!("reading key_file {}", key_file.display()))?;
            builder
                .with_client_auth_cert(chain, key)
                .context("cert_file and key_file")?
        }
        None => builder.with_no_client_auth(),
    };
    Ok(config)
}

/// The certificates of `ca_file`, which overrides the system's store.
fn ca_file_roots(ca_file: &Path) -> anyhow::Result<RootCertStore> {
    let mut roots = RootCertStore::empty();
    let (added, _ignored) = roots.add_parsable_certificates(certificates(ca_file, "ca_file")?);
    if added == 0 {
        bail!(
            "ca_file {} holds no usable CA certificate",
            ca_file.display()
        );
    }
    Ok(roots)
}

/// The system's trust store. Certificates it cannot parse are skipped (a distribution's
/// bundle may hold some rustls refuses); a store with none left is an error that says how to
/// give one.
fn system_roots() -> anyhow::Result<RootCertStore> {
    let found = rustls_native_certs::load_native_certs();
    for error in &found.errors {
        tracing::warn!(%error, "system trust store: a certificate source could not be read");
    }
    let mut roots = RootCertStore::empty();
    let (added, ignored) = roots.add_parsable_certificates(found.certs);
    tracing::debug!(added, ignored, "system trust store loaded");
    if added == 0 {
        bail!(
            "mqtts:// without ca_file verifies the broker against the system trust store, and it \
             holds no certificate: set mqtt.ca_file, or SSL_CERT_FILE to a CA bundle"
        );
    }
    Ok(roots)
}

/// Every PEM certificate in `path` (the configuration key `key` names it in errors).
fn certificates(path: &Path, key: &str) -> anyhow::Result<Vec<CertificateDer<'static>>> {
    let chain = CertificateDer::pem_file_iter(path)
        .and_then(|items| items.collect::<Result<Vec<_>, _>>())
        .with_context(|| format!("reading {key} {}", path.display()))?;
    if chain.is_empty() {
        bail!("{key} {} holds no PEM certificate", path.display());
    }
    Ok(chain)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_ca_file_without_a_certificate_is_refused_with_its_key() {
        let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
        let path = dir.path().join("ca.crt");
        std::fs::write(&path, "not a certificate\n").unwrap_or_else(|e| panic!("{e}"));
        let settings = TlsSettings {
            ca_file: Some(path),
            client_auth: None,
        };
        let error = match client_config(&settings) {
            Ok(_) => panic!("accepted a CA file without a certificate"),
            Err(error) => format!("{error:#}"),
        };
        assert!(error.contains("ca_file"), "{error}");
    }
}
