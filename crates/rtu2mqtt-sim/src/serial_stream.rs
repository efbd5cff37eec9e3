//! An async byte stream over a serial port or a pty end, for the simulators: a
//! `mio_serial::SerialStream` (the serial crate the gateway's transport uses too) registered
//! with tokio's reactor, read and written like any other tokio stream.

use std::io::{self, Read as _, Write as _};
use std::pin::Pin;
use std::task::{ready, Context, Poll};

use mio_serial::SerialPortBuilder;
use tokio::io::unix::AsyncFd;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};

/// A serial port (or pty end) readable and writable from async code.
#[derive(Debug)]
pub struct AsyncSerial {
    port: AsyncFd<mio_serial::SerialStream>,
}

impl AsyncSerial {
    /// Takes over an open port. Needs a tokio runtime with I/O enabled.
    pub fn new(port: mio_serial::SerialStream) -> io::Result<Self> {
        // SAFETY: the AsyncFd owns the stream, whose descriptor stays open and the same until
        // the AsyncFd is dropped (nothing here replaces or closes it).
        let port = unsafe { AsyncFd::register(port) }.map_err(io::Error::from)?;
        Ok(Self { port })
    }

    /// Opens the port `builder` describes (exclusively, as every serial port is opened here).
    pub fn open(builder: &SerialPortBuilder) -> io::Result<Self> {
        Self::new(mio_serial::SerialStream::open(builder)?)
    }

    /// The port itself, for its settings and its name.
    pub fn port(&self) -> &mio_serial::SerialStream {
        self.port.get_ref()
    }
}

impl AsyncRead for AsyncSerial {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        loop {
            let mut guard = ready!(self.port.poll_read_ready(cx))?;
            match guard.try_io(|port| port.get_ref().read(buf.initialize_unfilled())) {
                Ok(Ok(count)) => {
                    buf.advance(count);
                    return Poll::Ready(Ok(()));
                }
                Ok(Err(error)) => return Poll::Ready(Err(error)),
                // Readiness was stale: wait for the next edge.
                Err(_would_block) => continue,
            }
        }
    }
}

impl AsyncWrite for AsyncSerial {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bytes: &[u8],
    ) -> Poll<io::Result<usize>> {
        loop {
            let mut guard = ready!(self.port.poll_write_ready(cx))?;
            match guard.try_io(|port| port.get_ref().write(bytes)) {
                Ok(result) => return Poll::Ready(result),
                Err(_would_block) => continue,
            }
        }
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        loop {
            let mut guard = ready!(self.port.poll_write_ready(cx))?;
            // Flushing drains the kernel's output buffer (tcdrain). A pty whose other end is
            // gone reports that on the next write, as a real port does: not here.
            match guard.try_io(|port| port.get_ref().flush()) {
                Ok(_) => return Poll::Ready(Ok(())),
                Err(_would_block) => continue,
            }
        }
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        self.poll_flush(cx)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};

    #[tokio::test]
    async fn bytes_cross_a_pty_pair_both_ways() {
        let (master, slave) = mio_serial::SerialStream::pair().expect("a pty pair");
        let mut master = AsyncSerial::new(master).expect("registered");
        let mut slave = AsyncSerial::new(slave).expect("registered");
        master
            .write_all(&[0x01, 0x03, 0x00])
            .await
            .expect("written");
        let mut got = [0u8; 3];
        slave.read_exact(&mut got).await.expect("read");
        assert_eq!(got, [0x01, 0x03, 0x00]);
        slave.write_all(b"ok").await.expect("written");
        let mut got = [0u8; 2];
        master.read_exact(&mut got).await.expect("read");
        assert_eq!(&got, b"ok");
    }
}
