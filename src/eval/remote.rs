//! The client side of openpi's policy-server protocol over a WebSocket (`tungstenite`,
//! synchronous, no TLS): on connecting, the server sends one metadata message; then each
//! request (a binary msgpack message, see [`super::numpy`]) gets one binary reply. A text reply
//! is the server's error (openpi sends its traceback, then closes).
//!
//! Each request with its whole reply (pings and partial frames included) takes at most the
//! time-out ([`DeadlineStream`]). After any failure (time-out, error text, closed
//! connection, malformed reply) the connection is dropped, since a late reply would answer the
//! wrong request, and the next request reconnects ([`RECONNECT_ATTEMPTS`] tries).

use std::io::ErrorKind as IoKind;
use std::net::{TcpStream, ToSocketAddrs};
use std::time::{Duration, Instant};
use tungstenite::{Message, WebSocket};

/// Connection attempts before a request fails (the first connection at start is tried once).
pub const RECONNECT_ATTEMPTS: u32 = 3;

/// Why a policy server could not answer.
#[derive(Debug, thiserror::Error)]
pub enum RemoteError {
    #[error("{url} is not a policy server address: {why}")]
    Address { url: String, why: String },
    #[error("cannot connect to the policy server at {url}")]
    Connect {
        url: String,
        #[source]
        source: std::io::Error,
    },
    #[error("the WebSocket handshake with {url} failed")]
    Handshake {
        url: String,
        #[source]
        source: Box<tungstenite::Error>,
    },
    #[error("no reply from {url} within {secs} s")]
    Timeout { url: String, secs: f64 },
    #[error("the policy server at {url} closed the connection")]
    Closed { url: String },
    #[error("the policy server at {url} reported an error: {text}")]
    Server { url: String, text: String },
    #[error("talking to the policy server at {url}")]
    Io {
        url: String,
        #[source]
        source: Box<tungstenite::Error>,
    },
}

/// A TCP stream whose every read and write ends by one deadline (set per request, so the time-out
/// covers the whole reply, whatever the server sends meanwhile: pings, or a reply trickled a few
/// bytes at a time).
struct DeadlineStream {
    stream: TcpStream,
    deadline: Instant,
}

impl DeadlineStream {
    /// The time left, or a time-out error once the deadline has passed.
    fn remaining(&self) -> std::io::Result<Duration> {
        let left = self.deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return Err(std::io::Error::from(IoKind::TimedOut));
        }
        Ok(left)
    }
}

impl std::io::Read for DeadlineStream {
    fn read(&mut self, buffer: &mut [u8]) -> std::io::Result<usize> {
        let left = self.remaining()?;
        self.stream.set_read_timeout(Some(left))?;
        self.stream.read(buffer)
    }
}

impl std::io::Write for DeadlineStream {
    fn write(&mut self, bytes: &[u8]) -> std::io::Result<usize> {
        let left = self.remaining()?;
        self.stream.set_write_timeout(Some(left))?;
        self.stream.write(bytes)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.stream.flush()
    }
}

/// A connection to one policy server.
pub struct RemotePolicy {
    url: String,
    host_port: String,
    timeout: Duration,
    socket: Option<WebSocket<DeadlineStream>>,
    /// The metadata message of the latest connection (msgpack bytes).
    pub metadata: Vec<u8>,
}

impl std::fmt::Debug for RemotePolicy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RemotePolicy")
            .field("url", &self.url)
            .field("connected", &self.socket.is_some())
            .finish()
    }
}

impl RemotePolicy {
    /// Connects to `url` (`ws://HOST:PORT[/PATH]`) and reads the server's metadata; `timeout`
    /// bounds the connection and every reply.
    pub fn connect(url: &str, timeout: Duration) -> Result<RemotePolicy, RemoteError> {
        let address = |why: &str| RemoteError::Address {
            url: url.to_string(),
            why: why.to_string(),
        };
        let rest = url
            .strip_prefix("ws://")
            .ok_or_else(|| address("expected ws://HOST:PORT (wss:// is not supported)"))?;
        let host_port = rest.split('/').next().unwrap_or_default().to_string();
        if host_port.is_empty() || timeout.is_zero() {
            return Err(address("no host, or a zero time-out"));
        }
        let with_port = if host_port
            .rsplit_once(':')
            .is_some_and(|(_, p)| p.parse::<u16>().is_ok())
        {
            host_port
        } else {
            format!("{host_port}:80")
        };
        let mut policy = RemotePolicy {
            url: url.to_string(),
            host_port: with_port,
            timeout,
            socket: None,
            metadata: Vec::new(),
        };
        policy.open()?;
        Ok(policy)
    }

    pub fn url(&self) -> &str {
        &self.url
    }

    fn open(&mut self) -> Result<(), RemoteError> {
        let connect_error = |source| RemoteError::Connect {
            url: self.url.clone(),
            source,
        };
        let addresses: Vec<_> = self
            .host_port
            .to_socket_addrs()
            .map_err(connect_error)?
            .collect();
        let mut last = std::io::Error::new(IoKind::NotFound, "the host has no address");
        let mut stream = None;
        for address in addresses {
            match TcpStream::connect_timeout(&address, self.timeout) {
                Ok(s) => {
                    stream = Some(s);
                    break;
                }
                Err(e) => last = e,
            }
        }
        let stream = stream.ok_or_else(|| connect_error(last))?;
        let configure = stream
            .set_read_timeout(Some(self.timeout))
            .and_then(|()| stream.set_write_timeout(Some(self.timeout)))
            .and_then(|()| stream.set_nodelay(true));
        configure.map_err(connect_error)?;
        let stream = DeadlineStream {
            stream,
            deadline: Instant::now() + self.timeout,
        };
        let (socket, _) = tungstenite::client(self.url.as_str(), stream).map_err(|e| match e {
            tungstenite::HandshakeError::Failure(e) => RemoteError::Handshake {
                url: self.url.clone(),
                source: Box::new(e),
            },
            tungstenite::HandshakeError::Interrupted(_) => RemoteError::Timeout {
                url: self.url.clone(),
                secs: self.timeout.as_secs_f64(),
            },
        })?;
        self.socket = Some(socket);
        self.metadata = self.receive()?;
        Ok(())
    }

    /// Sends one request and returns the reply's bytes.
    pub fn infer(&mut self, request: Vec<u8>) -> Result<Vec<u8>, RemoteError> {
        if self.socket.is_none() {
            let mut attempt = 1;
            while let Err(e) = self.open() {
                self.socket = None;
                if attempt >= RECONNECT_ATTEMPTS {
                    return Err(e);
                }
                std::thread::sleep(Duration::from_millis(200 * u64::from(attempt)));
                attempt += 1;
            }
        }
        let result = self.exchange(request);
        if result.is_err() {
            self.disconnect();
        }
        result
    }

    fn exchange(&mut self, request: Vec<u8>) -> Result<Vec<u8>, RemoteError> {
        let url = self.url.clone();
        let socket = self.socket.as_mut().ok_or(RemoteError::Closed { url })?;
        // One deadline for the request and its whole reply.
        socket.get_mut().deadline = Instant::now() + self.timeout;
        socket
            .send(Message::Binary(request.into()))
            .map_err(|e| self.failure(e))?;
        self.receive()
    }

    /// The next binary message.
    fn receive(&mut self) -> Result<Vec<u8>, RemoteError> {
        loop {
            let url = self.url.clone();
            let socket = self.socket.as_mut().ok_or(RemoteError::Closed { url })?;
            match socket.read().map_err(|e| self.failure(e))? {
                Message::Binary(bytes) => return Ok(bytes.to_vec()),
                Message::Text(text) => {
                    return Err(RemoteError::Server {
                        url: self.url.clone(),
                        text: text.as_str().trim().to_string(),
                    });
                }
                Message::Close(_) => {
                    return Err(RemoteError::Closed {
                        url: self.url.clone(),
                    });
                }
                Message::Ping(_) | Message::Pong(_) | Message::Frame(_) => {}
            }
        }
    }

    fn failure(&self, error: tungstenite::Error) -> RemoteError {
        let url = self.url.clone();
        match error {
            tungstenite::Error::Io(e)
                if matches!(e.kind(), IoKind::WouldBlock | IoKind::TimedOut) =>
            {
                RemoteError::Timeout {
                    url,
                    secs: self.timeout.as_secs_f64(),
                }
            }
            tungstenite::Error::ConnectionClosed
            | tungstenite::Error::AlreadyClosed
            | tungstenite::Error::Protocol(
                tungstenite::error::ProtocolError::ResetWithoutClosingHandshake,
            ) => RemoteError::Closed { url },
            tungstenite::Error::Io(e)
                if matches!(
                    e.kind(),
                    IoKind::ConnectionReset | IoKind::BrokenPipe | IoKind::UnexpectedEof
                ) =>
            {
                RemoteError::Closed { url }
            }
            other => RemoteError::Io {
                url,
                source: Box::new(other),
            },
        }
    }

    /// Drops the connection (the next request reconnects).
    pub fn disconnect(&mut self) {
        if let Some(mut socket) = self.socket.take() {
            let _ = socket.close(None);
        }
    }
}

impl Drop for RemotePolicy {
    fn drop(&mut self) {
        self.disconnect();
    }
}
