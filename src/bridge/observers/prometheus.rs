//! The optional Prometheus endpoint: a tiny HTTP/1.1 responder on tokio that answers
//! `GET /metrics` with the text of a render function (the lines' statistics and the bridge's
//! counters), 404 to other paths and 405 to other methods, one request per connection. Off
//! unless `gateway.metrics_listen` is set. Requests are bounded in size and time.

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};

use tokio_util::sync::CancellationToken;

/// Largest request head read; a scraper's is a few hundred bytes.
const MAX_REQUEST: usize = 8 * 1024;
/// A client that does not finish its request (or read the answer) in this time is dropped.
const IO_TIMEOUT: Duration = Duration::from_secs(5);

/// Produces the exposition text on demand.
pub type Render = Arc<dyn Fn() -> String + Send + Sync>;

/// Binds `address` (an error here is reported at start) and serves until `shutdown`.
pub async fn bind(address: SocketAddr) -> std::io::Result<TcpListener> {
    TcpListener::bind(address).await
}

/// Serves `/metrics` on `listener` until `shutdown` fires.
pub async fn serve(listener: TcpListener, render: Render, shutdown: CancellationToken) {
    loop {
        let accepted = tokio::select! {
            _ = shutdown.cancelled() => return,
            accepted = listener.accept() => accepted,
        };
        match accepted {
            Ok((stream, _peer)) => {
                let render = render.clone();
                tokio::spawn(async move {
                    let _ = tokio::time::timeout(IO_TIMEOUT, answer(stream, render)).await;
                });
            }
            Err(error) => {
                tracing::warn!(%error, "metrics endpoint: accept failed");
                // Out of file descriptors and the like: do not spin.
                tokio::time::sleep(Duration::from_millis(100)).await;
            }
        }
    }
}

async fn answer(mut stream: TcpStream, render: Render) -> std::io::Result<()> {
    let mut head = Vec::with_capacity(512);
    let mut buffer = [0u8; 1024];
    while !head.windows(4).any(|w| w == b"\r\n\r\n") {
        let read = stream.read(&mut buffer).await?;
        if read == 0 {
            break;
        }
        head.extend_from_slice(&buffer[..read]);
        if head.len() > MAX_REQUEST {
            drain_request(&mut stream, &head).await;
            return respond(&mut stream, "431 Request Header Fields Too Large", "").await;
        }
    }
    let request_line = head
        .split(|&b| b == b'\n')
        .next()
        .map(|line| String::from_utf8_lossy(line).trim().to_string())
        .unwrap_or_default();
    let mut parts = request_line.split_whitespace();
    let (method, target) = (parts.next().unwrap_or(""), parts.next().unwrap_or(""));
    let path = target.split('?').next().unwrap_or("");
    match (method, path) {
        ("GET", "/metrics") => respond(&mut stream, "200 OK", &render()).await,
        ("HEAD", "/metrics") => respond(&mut stream, "200 OK", "").await,
        (_, "/metrics") => respond(&mut stream, "405 Method Not Allowed", "").await,
        _ => respond(&mut stream, "404 Not Found", "only /metrics here\n").await,
    }
}

/// Reads (and forgets) the rest of an oversized request head, up to a bound, so that closing
/// the connection does not reset it before the client has read the answer.
async fn drain_request(stream: &mut TcpStream, seen: &[u8]) {
    const DRAIN_LIMIT: usize = 64 * 1024;
    let mut tail: Vec<u8> = seen[seen.len().saturating_sub(3)..].to_vec();
    let mut total = seen.len();
    let mut buffer = [0u8; 4096];
    while total < DRAIN_LIMIT {
        let Ok(read) = stream.read(&mut buffer).await else {
            return;
        };
        if read == 0 {
            return;
        }
        total += read;
        tail.extend_from_slice(&buffer[..read]);
        if tail.windows(4).any(|w| w == b"\r\n\r\n") {
            return;
        }
        tail.drain(..tail.len().saturating_sub(3));
    }
}

async fn respond(stream: &mut TcpStream, status: &str, body: &str) -> std::io::Result<()> {
    let response = format!(
        "HTTP/1.1 {status}\r\nContent-Type: text/plain; version=0.0.4; charset=utf-8\r\n\
         Content-Length: {}\r\nConnection: close\r\n\r\n{body}",
        body.len()
    );
    stream.write_all(response.as_bytes()).await?;
    stream.shutdown().await
}

#[cfg(test)]
mod tests {
    use super::*;

    async fn get(address: SocketAddr, request: &str) -> String {
        let mut stream = TcpStream::connect(address).await.unwrap();
        stream.write_all(request.as_bytes()).await.unwrap();
        let mut response = String::new();
        stream.read_to_string(&mut response).await.unwrap();
        response
    }

    #[tokio::test]
    async fn serves_metrics_and_nothing_else() {
        let listener = bind("127.0.0.1:0".parse().unwrap()).await.unwrap();
        let address = listener.local_addr().unwrap();
        let shutdown = CancellationToken::new();
        let trigger = shutdown.clone();
        let render: Render = Arc::new(|| "rtu2mqtt_up 1\n".to_string());
        let server = tokio::spawn(serve(listener, render, shutdown));

        let ok = get(address, "GET /metrics HTTP/1.1\r\nHost: x\r\n\r\n").await;
        assert!(ok.starts_with("HTTP/1.1 200 OK\r\n"), "{ok}");
        assert!(ok.contains("Content-Length: 14\r\n"), "{ok}");
        assert!(ok.ends_with("\r\n\r\nrtu2mqtt_up 1\n"), "{ok}");

        let missing = get(address, "GET / HTTP/1.1\r\n\r\n").await;
        assert!(missing.starts_with("HTTP/1.1 404"), "{missing}");
        let post = get(address, "POST /metrics HTTP/1.1\r\n\r\n").await;
        assert!(post.starts_with("HTTP/1.1 405"), "{post}");
        let huge = format!("GET /metrics HTTP/1.1\r\nX: {}\r\n\r\n", "a".repeat(20_000));
        let refused = get(address, &huge).await;
        assert!(refused.starts_with("HTTP/1.1 431"), "{refused}");

        trigger.cancel();
        server.await.unwrap();
    }
}
