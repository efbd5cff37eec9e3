//! The HTTP server's own accept loop: a bounded number of connections, each with a deadline
//! for its TLS handshake and its request head and a cap on the head's size, served by hyper
//! with an axum router. A client that connects and sends nothing, or sends slowly, holds one
//! connection until its deadline and nothing else: the gateway's loops never wait on it.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use anyhow::Context as _;
use axum::Router;
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::service::TowerToHyperService;
use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, PrivateKeyDer};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::Semaphore;
use tokio_rustls::TlsAcceptor;
use tokio_util::sync::CancellationToken;

/// Connections served at once; more wait in the kernel's backlog.
pub const MAX_CONNECTIONS: usize = 64;
/// A client has this long to finish its TLS handshake and each request head.
pub const HEAD_DEADLINE: Duration = Duration::from_secs(10);
/// Largest request head (request line and headers).
pub const MAX_HEAD: usize = 16 * 1024;

/// A bound socket, with the TLS configuration when it speaks HTTPS.
pub struct Listener {
    socket: TcpListener,
    tls: Option<TlsAcceptor>,
}

impl std::fmt::Debug for Listener {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Listener")
            .field("socket", &self.socket)
            .field("tls", &self.tls.is_some())
            .finish()
    }
}

impl Listener {
    /// Binds `address` and reads the certificate and key of `tls`: an error here stops the
    /// start, with the reason.
    pub async fn bind(
        address: SocketAddr,
        tls: Option<&(PathBuf, PathBuf)>,
    ) -> anyhow::Result<Listener> {
        let tls = tls.map(|(cert, key)| acceptor(cert, key)).transpose()?;
        let socket = TcpListener::bind(address)
            .await
            .with_context(|| format!("listening on {address}"))?;
        Ok(Listener { socket, tls })
    }

    /// A socket bound already (by whoever picked the port), with `tls` as [`Listener::bind`].
    pub fn from_std(
        socket: std::net::TcpListener,
        tls: Option<&(PathBuf, PathBuf)>,
    ) -> anyhow::Result<Listener> {
        let tls = tls.map(|(cert, key)| acceptor(cert, key)).transpose()?;
        socket
            .set_nonblocking(true)
            .context("the console's socket")?;
        let socket = TcpListener::from_std(socket).context("the console's socket")?;
        Ok(Listener { socket, tls })
    }

    /// The address bound (the port the kernel chose for `:0`).
    pub fn local_addr(&self) -> std::io::Result<SocketAddr> {
        self.socket.local_addr()
    }

    /// Serves `router` on every accepted connection until `shutdown`.
    pub async fn serve(self, router: Router, shutdown: CancellationToken) {
        let places = Arc::new(Semaphore::new(MAX_CONNECTIONS));
        loop {
            let Ok(place) = Arc::clone(&places).acquire_owned().await else {
                return;
            };
            let accepted = tokio::select! {
                _ = shutdown.cancelled() => return,
                accepted = self.socket.accept() => accepted,
            };
            let (stream, peer) = match accepted {
                Ok(accepted) => accepted,
                Err(error) => {
                    tracing::warn!(%error, "web: accept failed");
                    // Out of file descriptors and the like: do not spin.
                    tokio::time::sleep(Duration::from_millis(100)).await;
                    continue;
                }
            };
            let router = router.clone();
            let tls = self.tls.clone();
            let shutdown = shutdown.clone();
            tokio::spawn(async move {
                let _place = place;
                serve_connection(stream, peer, tls, router, shutdown).await;
            });
        }
    }
}

async fn serve_connection(
    stream: TcpStream,
    peer: SocketAddr,
    tls: Option<TlsAcceptor>,
    router: Router,
    shutdown: CancellationToken,
) {
    let _ = stream.set_nodelay(true);
    match tls {
        Some(acceptor) => {
            match tokio::time::timeout(HEAD_DEADLINE, acceptor.accept(stream)).await {
                Ok(Ok(stream)) => http(stream, router, shutdown).await,
                Ok(Err(error)) => tracing::debug!(%peer, %error, "web: TLS handshake failed"),
                Err(_) => tracing::debug!(%peer, "web: TLS handshake too slow"),
            }
        }
        None => http(stream, router, shutdown).await,
    }
}

async fn http<S>(stream: S, router: Router, shutdown: CancellationToken)
where
    S: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin + Send + 'static,
{
    let service = TowerToHyperService::new(router);
    let mut builder = hyper::server::conn::http1::Builder::new();
    builder
        .timer(TokioTimer::new())
        .header_read_timeout(HEAD_DEADLINE)
        .max_buf_size(MAX_HEAD)
        .keep_alive(true);
    let connection = builder.serve_connection(TokioIo::new(stream), service);
    let mut connection = std::pin::pin!(connection);
    tokio::select! {
        _ = connection.as_mut() => {}
        _ = shutdown.cancelled() => {
            // Event streams never end by themselves: the server's end closes them.
            connection.as_mut().graceful_shutdown();
            let _ = tokio::time::timeout(Duration::from_secs(1), connection).await;
        }
    }
}

/// The TLS acceptor for a PEM certificate chain and key.
fn acceptor(cert: &PathBuf, key: &PathBuf) -> anyhow::Result<TlsAcceptor> {
    let chain = CertificateDer::pem_file_iter(cert)
        .with_context(|| format!("web.cert_file {}", cert.display()))?
        .collect::<Result<Vec<_>, _>>()
        .with_context(|| format!("web.cert_file {}", cert.display()))?;
    if chain.is_empty() {
        anyhow::bail!("web.cert_file {}: no certificate in it", cert.display());
    }
    let key = PrivateKeyDer::from_pem_file(key)
        .with_context(|| format!("web.key_file {}", key.display()))?;
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let config = rustls::ServerConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .context("TLS versions")?
        .with_no_client_auth()
        .with_single_cert(chain, key)
        .context("web.cert_file and web.key_file do not make a certificate")?;
    Ok(TlsAcceptor::from(Arc::new(config)))
}
