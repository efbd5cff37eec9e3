//! The MQTT connection (rumqttc): client options from the validated settings (Last Will,
//! credentials, TLS, bounds), and the task that polls rumqttc's event loop, turning what it
//! sees into [`LinkEvent`]s for the bridge. rumqttc reconnects on the very next poll, so this
//! task waits a capped, jittered exponential back-off after every connection error; a
//! connection that dies young (a client-id takeover, an auth refusal) keeps the back-off
//! growing instead of resetting it. Connections the broker keeps closing right after they
//! are made are what a second client with the same client id causes: said once, plainly.
//! History publishes rumqttc still holds when a connection ends (sent but not acknowledged, or
//! still queued) are taken back from it and handed to the bridge, which journals them: rumqttc
//! would otherwise drop them (a new session) or send them ahead of older journaled records.
//! A publish larger than the outgoing packet limit is refused before it reaches rumqttc
//! ([`PacketLimit`]): rumqttc would fail the whole connection on it, and send it again after
//! every reconnect. An incoming packet larger than [`MAX_INCOMING_PACKET`] is refused by
//! rumqttc unread, which ends the connection: it is made again, and [`super::oversized`] keeps
//! the same packet from coming straight back.

use std::collections::HashSet;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use rumqttc::{
    AsyncClient, ConnectionError, Event, EventLoop, LastWill, MqttOptions, Outgoing, Packet,
    Publish, QoS, TlsConfiguration, Transport,
};
use tokio::sync::{mpsc, watch};

use super::history_stream::is_history;
use super::oversized::{log_oversized, oversized, SubscriptionWatch};
use crate::config::MqttSettings;
use crate::topics::{Topics, OFFLINE};

/// First wait after a connection error.
pub const BACKOFF_INITIAL: Duration = Duration::from_millis(250);
/// Longest wait between two connection attempts.
pub const BACKOFF_MAX: Duration = Duration::from_secs(30);
/// A connection that lived this long resets the back-off.
const STABLE_CONNECTION: Duration = Duration::from_secs(10);
/// Requests the bridge may queue ahead of the event loop (all sends are `try_*`: a full queue
/// costs a message, never a blocked bridge).
pub const REQUEST_QUEUE: usize = 4096;
/// The bridge's own client queue: short, because the bridge holds what waits in its outbox
/// (ordered, coalesced, bounded) and its writer awaits room here instead of dropping.
pub const BRIDGE_REQUEST_QUEUE: usize = 64;
/// Connections that end within [`STABLE_CONNECTION`] in a row before a client-id clash is
/// reported.
const CLASH_SUSPECTED_AFTER: u32 = 3;
/// The largest incoming packet read (its remaining length; larger ones rumqttc refuses after
/// reading their length, before their body, and ends the connection). What the gateway
/// subscribes to is far smaller: commands (`gateway.max_payload`, at most 64 KiB, on a topic of
/// at most 64 KiB), its own retained topics and Home Assistant configs (it sends nothing larger
/// than [`MAX_OUTGOING_PACKET`]), Home Assistant's status (a word) and other integrations'
/// configs (kilobytes). The limit is 16 times that, so that a command far over `max_payload` is
/// still read, answered `rejected` and, when retained, cleared; the memory a message costs is
/// bounded by it whatever the broker accepts. What is larger is refused unread (see
/// [`super::oversized`]).
pub const MAX_INCOMING_PACKET: usize = 16 * MAX_OUTGOING_PACKET;
/// The largest packet the gateway sends. rumqttc checks every outgoing packet against it and
/// ends the connection on one that is larger (keeping it to send again after the reconnect),
/// so [`PacketLimit`] refuses such a publish before it is handed over. MQTT 3.1.1 has no way
/// for the broker to announce its own limit: a broker configured below this one closes the
/// connection on a packet it finds too large, so lower the broker's limit only with care.
pub const MAX_OUTGOING_PACKET: usize = 256 * 1024;

/// How long the event loop waits for the broker to close after our Disconnect.
const CLOSE_GRACE: Duration = Duration::from_secs(2);

/// What the event loop task reports to the bridge.
#[derive(Debug)]
pub enum LinkEvent {
    /// A ConnAck: (re)subscribe, announce, republish.
    Connected { session_present: bool },
    /// The connection is gone (the task backs off and retries); `unacknowledged` are the
    /// history publishes rumqttc held without a PUBACK, oldest first.
    Disconnected {
        reason: String,
        unacknowledged: Vec<Publish>,
    },
    /// An incoming publish.
    Message(Publish),
    /// Our Disconnect went out: the task ends, handing back the history publishes not
    /// acknowledged.
    Closed { unacknowledged: Vec<Publish> },
    /// A history publish the writer did not hand to the client because the link was down.
    Unsent(crate::bridge::core::Publish),
}

/// The size of a PUBLISH packet on `topic` with `payload_len` bytes of payload, as rumqttc
/// measures it against [`MAX_OUTGOING_PACKET`]: the fixed header (its remaining length takes 1
/// to 4 bytes), the topic with its length, the packet id of QoS 1 and 2, the payload.
pub fn publish_packet_size(topic: &str, payload_len: usize, qos: QoS) -> usize {
    let packet_id = if qos == QoS::AtMostOnce { 0 } else { 2 };
    let remaining = 2 + topic.len() + packet_id + payload_len;
    let length_bytes = match remaining {
        0..=127 => 1,
        128..=16_383 => 2,
        16_384..=2_097_151 => 3,
        _ => 4,
    };
    1 + length_bytes + remaining
}

/// The outgoing packet limit, applied by the gateway before rumqttc sees a publish: one that
/// is too large is refused alone (counted, logged once per topic) and the connection carries
/// on. Clones share the count, so the plain and the Sparkplug connection add to one figure.
#[derive(Debug, Clone)]
pub struct PacketLimit {
    max: usize,
    refused: Arc<AtomicU64>,
    /// Topics already named in the log.
    logged: HashSet<String>,
    /// Which connection this copy guards, for the log.
    connection: &'static str,
}

impl PacketLimit {
    /// A limit of `max` bytes per packet for the connection named `connection` in the log.
    pub fn new(max: usize, connection: &'static str) -> Self {
        PacketLimit {
            max,
            refused: Arc::new(AtomicU64::new(0)),
            logged: HashSet::new(),
            connection,
        }
    }

    /// A limit of `max` bytes for another connection, counting into the same figure.
    pub fn for_connection(&self, connection: &'static str, max: usize) -> Self {
        PacketLimit {
            max,
            refused: Arc::clone(&self.refused),
            logged: HashSet::new(),
            connection,
        }
    }

    /// Whether a publish on `topic` with `payload_len` bytes fits; one that does not is
    /// counted and, the first time on its topic, logged.
    pub fn admits(&mut self, topic: &str, payload_len: usize, qos: QoS) -> bool {
        let size = publish_packet_size(topic, payload_len, qos);
        if size <= self.max {
            return true;
        }
        self.refused.fetch_add(1, Ordering::Relaxed);
        if !self.logged.contains(topic) {
            self.logged.insert(topic.to_string());
            tracing::error!(connection = self.connection, %topic, size, max = self.max,
                "a message larger than the MQTT packet limit is not sent (sending it would end \
                 the connection); counted as mqtt.oversized_refused");
        }
        false
    }

    /// The largest packet admitted, in bytes (what rumqttc must be told too).
    pub fn max(&self) -> usize {
        self.max
    }

    /// Publishes refused so far, on every connection sharing this count.
    pub fn refused(&self) -> u64 {
        self.refused.load(Ordering::Relaxed)
    }
}

/// Whether the link is up, as the event loop task knows it first; the bridge's writer reads
/// it so that no history publish is handed to rumqttc while a connection is being lost.
pub type LinkFlag = Arc<AtomicBool>;

/// Takes every history publish out of rumqttc's list of what it would send again, in order.
fn take_history(eventloop: &mut EventLoop) -> Vec<Publish> {
    let mut taken = Vec::new();
    eventloop.pending.retain(|request| match request {
        rumqttc::Request::Publish(publish) if is_history(&publish.topic, publish.retain) => {
            taken.push(publish.clone());
            false
        }
        _ => true,
    });
    taken
}

/// The client's options: Last Will `offline` (retained) on the gateway status topic.
pub fn options(settings: &MqttSettings, topics: &Topics) -> anyhow::Result<MqttOptions> {
    let mut options = MqttOptions::new(&settings.client_id, &settings.host, settings.port);
    options
        .set_keep_alive(settings.keep_alive)
        .set_clean_session(settings.clean_session)
        .set_inflight(settings.inflight)
        .set_max_packet_size(MAX_INCOMING_PACKET, MAX_OUTGOING_PACKET)
        .set_request_channel_capacity(REQUEST_QUEUE)
        .set_last_will(LastWill::new(
            topics.gateway_status_topic(),
            OFFLINE,
            QoS::AtLeastOnce,
            true,
        ));
    if let Some(username) = &settings.username {
        options.set_credentials(username, settings.password.clone().unwrap_or_default());
    }
    if let Some(tls) = &settings.tls {
        let config = super::tls::client_config(tls)?;
        options.set_transport(Transport::tls_with_config(TlsConfiguration::Rustls(
            Arc::new(config),
        )));
    }
    Ok(options)
}

/// The client handle and its event loop (nothing is sent until the loop is polled).
pub fn connect(settings: &MqttSettings) -> anyhow::Result<(AsyncClient, EventLoop)> {
    let topics = settings.topics();
    let mut options = options(settings, &topics)?;
    options.set_request_channel_capacity(BRIDGE_REQUEST_QUEUE);
    Ok(client(options, BRIDGE_REQUEST_QUEUE))
}

/// A client and its event loop whose socket sends at once (`TCP_NODELAY`, plain and TLS alike:
/// TLS runs over the same socket). With Nagle on, a small publish that follows another one
/// not yet acknowledged waits for that acknowledgement (delayed by the broker's delayed ACK),
/// so a command's result would reach subscribers tens of milliseconds after the bus was done.
pub fn client(options: MqttOptions, request_queue: usize) -> (AsyncClient, EventLoop) {
    let (client, mut eventloop) = AsyncClient::new(options, request_queue);
    // Start from the loop's own options so its other defaults (the connect timeout) stay.
    let mut network = eventloop.network_options();
    network.set_tcp_nodelay(true);
    eventloop.set_network_options(network);
    (client, eventloop)
}

/// Whether a failed connection attempt got as far as sending its CONNECT packet. An attempt
/// ends before it when the broker's name cannot be resolved, its TCP connection is refused or
/// cannot be routed, or the TLS handshake fails (TLS comes before CONNECT). What cannot be
/// told apart (rumqttc's time limit on the whole attempt, a connection closed once it was
/// up) counts as sent: a bdSeq must never be used twice, while one skipped is harmless.
pub fn connect_went_out(error: &ConnectionError) -> bool {
    use std::io::ErrorKind;
    match error {
        ConnectionError::Tls(_) => false,
        ConnectionError::Io(error) => {
            let before_connect = matches!(
                error.kind(),
                ErrorKind::ConnectionRefused
                    | ErrorKind::HostUnreachable
                    | ErrorKind::NetworkUnreachable
                    | ErrorKind::AddrNotAvailable
                    | ErrorKind::InvalidInput
            ) || is_name_lookup_failure(error);
            !before_connect
        }
        _ => true,
    }
}

/// A failed name lookup: std reports getaddrinfo's errors with no OS error code and a kind
/// that cannot be matched on, only by this message.
fn is_name_lookup_failure(error: &std::io::Error) -> bool {
    error.raw_os_error().is_none()
        && error
            .to_string()
            .starts_with("failed to lookup address information")
}

/// Capped exponential back-off with ±20 % jitter (so a fleet does not reconnect in step).
#[derive(Debug, Clone)]
pub struct Backoff {
    next: Duration,
}

impl Default for Backoff {
    fn default() -> Self {
        Backoff {
            next: BACKOFF_INITIAL,
        }
    }
}

impl Backoff {
    /// The wait before the next attempt; doubles the one after (up to the cap).
    pub fn next_wait(&mut self) -> Duration {
        let base = self.next;
        self.next = (self.next * 2).min(BACKOFF_MAX);
        let jitter = rand::random::<f64>() * 0.4 + 0.8;
        base.mul_f64(jitter).min(BACKOFF_MAX)
    }

    pub fn reset(&mut self) {
        self.next = BACKOFF_INITIAL;
    }
}

/// Takes what rumqttc read before a connection failed and would hand over only after the next
/// ConnAck: it belongs to the connection that ended.
pub fn take_held_events(eventloop: &mut EventLoop) -> Vec<Event> {
    eventloop.state.events.drain(..).collect()
}

/// Takes the subscriptions rumqttc had taken and not sent out of what it would send on the
/// next connection, in order: every connection subscribes anew.
fn take_unsent_subscriptions(eventloop: &mut EventLoop) -> Vec<String> {
    let mut filters = Vec::new();
    eventloop.pending.retain(|request| match request {
        rumqttc::Request::Subscribe(subscribe) => {
            filters.extend(subscribe.filters.iter().map(|filter| filter.path.clone()));
            false
        }
        _ => true,
    });
    filters
}

/// Polls `eventloop` until our Disconnect goes out or the bridge is gone. `subscriptions` is
/// told what goes out and comes in (the writer hands the subscriptions through it).
pub fn spawn_event_loop(
    mut eventloop: EventLoop,
    events_tx: mpsc::Sender<LinkEvent>,
    client_id: String,
    link: LinkFlag,
    mut give_back: watch::Receiver<bool>,
    subscriptions: SubscriptionWatch,
) -> tokio::task::JoinHandle<()> {
    tokio::spawn(async move {
        let mut backoff = Backoff::default();
        let mut clash = ClashWatch::default();
        let mut connected_since: Option<Instant> = None;
        let mut reported_down = false;
        // Failed attempts since the link went down, for the log.
        let mut failed_attempts: u32 = 0;
        // The session asked for; a connection after an oversized packet starts a clean one.
        let clean_session = eventloop.mqtt_options.clean_session();
        loop {
            let polled = tokio::select! {
                polled = eventloop.poll() => polled,
                // A stop whose Disconnect cannot get out (a broker that stopped reading): what
                // rumqttc holds is given back before the task is ended.
                () = asked(&mut give_back) => {
                    link.store(false, Ordering::SeqCst);
                    eventloop.clean();
                    let unacknowledged = take_history(&mut eventloop);
                    let _ = events_tx.send(LinkEvent::Closed { unacknowledged }).await;
                    return;
                }
            };
            if let Ok(event) = &polled {
                subscriptions.seen(event);
            }
            let event = match polled {
                Ok(Event::Incoming(Packet::ConnAck(connack))) => {
                    eventloop.mqtt_options.set_clean_session(clean_session);
                    connected_since = Some(Instant::now());
                    reported_down = false;
                    failed_attempts = 0;
                    tracing::info!(session_present = connack.session_present, "MQTT connected");
                    link.store(true, Ordering::SeqCst);
                    LinkEvent::Connected {
                        session_present: connack.session_present,
                    }
                }
                Ok(Event::Incoming(Packet::Publish(publish))) => LinkEvent::Message(publish),
                Ok(Event::Outgoing(Outgoing::Disconnect)) => {
                    // Read until the broker closes: dropping a socket with unread acks in it
                    // resets the connection, which can lose what was just sent (the offline
                    // announcements) and makes the broker publish our Will.
                    let drain = async { while eventloop.poll().await.is_ok() {} };
                    let _ = tokio::time::timeout(CLOSE_GRACE, drain).await;
                    link.store(false, Ordering::SeqCst);
                    eventloop.clean();
                    let unacknowledged = take_history(&mut eventloop);
                    let _ = events_tx.send(LinkEvent::Closed { unacknowledged }).await;
                    return;
                }
                Ok(_) => continue,
                Err(error) => {
                    // Messages read before the failure go to the bridge first, as they came.
                    for event in take_held_events(&mut eventloop) {
                        subscriptions.seen(&event);
                        if let Event::Incoming(Packet::Publish(publish)) = event {
                            if events_tx.send(LinkEvent::Message(publish)).await.is_err() {
                                return;
                            }
                        }
                    }
                    let unsent = take_unsent_subscriptions(&mut eventloop);
                    let oversized = oversized(&error);
                    let blame = subscriptions.connection_ended(
                        &unsent,
                        oversized.is_some(),
                        Instant::now(),
                    );
                    if let Some(size) = oversized {
                        // A message the broker keeps for a persistent session would come again
                        // at once: that session is given up.
                        eventloop.mqtt_options.set_clean_session(true);
                        log_oversized("plain", size, MAX_INCOMING_PACKET, &blame, !clean_session);
                    }
                    if let Some(since) = connected_since.take() {
                        let lived = since.elapsed();
                        if lived >= STABLE_CONNECTION {
                            backoff.reset();
                        }
                        // A connection ended by what the broker sent is no client-id clash.
                        if oversized.is_none() && clash.connection_ended(lived) {
                            tracing::error!(client_id = %client_id,
                                "the broker keeps closing this gateway's connection right after it is made: \
                                 another client probably uses the same client id (each connection takes \
                                 the other's session over, so availability flaps); give each gateway its \
                                 own mqtt.client_id");
                        }
                    }
                    let wait = backoff.next_wait();
                    log_connection_error(&error, wait, failed_attempts);
                    failed_attempts = failed_attempts.saturating_add(1);
                    let unacknowledged = take_history(&mut eventloop);
                    if !reported_down || !unacknowledged.is_empty() {
                        reported_down = true;
                        let down = LinkEvent::Disconnected {
                            reason: error.to_string(),
                            unacknowledged,
                        };
                        if events_tx.send(down).await.is_err() {
                            return;
                        }
                    }
                    // Only now: what the writer holds back from here on is journaled after
                    // what was taken back above.
                    link.store(false, Ordering::SeqCst);
                    tokio::time::sleep(wait).await;
                    if events_tx.is_closed() {
                        return;
                    }
                    continue;
                }
            };
            if events_tx.send(event).await.is_err() {
                return;
            }
        }
    })
}

/// Ready once `flag` is set; never when its sender is gone without setting it.
async fn asked(flag: &mut watch::Receiver<bool>) {
    if flag.wait_for(|set| *set).await.is_err() {
        std::future::pending::<()>().await;
    }
}

/// Counts connections that die young in a row; says once when that looks like a client-id
/// clash.
#[derive(Debug, Default)]
struct ClashWatch {
    young_in_a_row: u32,
    reported: bool,
}

impl ClashWatch {
    /// A connection ended after `lived`; true the one time a clash should be reported.
    fn connection_ended(&mut self, lived: Duration) -> bool {
        if lived >= STABLE_CONNECTION {
            self.young_in_a_row = 0;
            return false;
        }
        self.young_in_a_row += 1;
        if self.young_in_a_row >= CLASH_SUSPECTED_AFTER && !self.reported {
            self.reported = true;
            return true;
        }
        false
    }
}

/// One line per back-off step, with the wait before the next attempt: the link going down
/// (or the first attempt failing), then every failed reconnect attempt. The back-off caps the
/// rate at one line per [`BACKOFF_MAX`].
fn log_connection_error(error: &ConnectionError, wait: Duration, failed_attempts: u32) {
    let wait = humantime::format_duration(Duration::from_millis(wait.as_millis() as u64));
    if failed_attempts == 0 {
        tracing::warn!(%error, retry_in = %wait, "MQTT connection lost");
    } else {
        tracing::warn!(%error, attempt = failed_attempts, retry_in = %wait, "MQTT reconnect failed");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_attempts_that_reached_the_broker_count_as_a_connect_sent() {
        use std::io::{Error, ErrorKind};
        let io = |kind| ConnectionError::Io(Error::from(kind));
        for unsent in [
            io(ErrorKind::ConnectionRefused),
            io(ErrorKind::HostUnreachable),
            io(ErrorKind::NetworkUnreachable),
            ConnectionError::Tls(rumqttc::TlsError::NoValidCertInChain),
        ] {
            assert!(!connect_went_out(&unsent), "{unsent}");
        }
        // A real failed lookup, as std reports it.
        let lookup = std::net::ToSocketAddrs::to_socket_addrs("no-such-host.invalid:1883")
            .err()
            .map(ConnectionError::Io);
        if let Some(lookup) = lookup {
            assert!(!connect_went_out(&lookup), "{lookup}");
        }
        for sent in [
            io(ErrorKind::UnexpectedEof),
            io(ErrorKind::ConnectionReset),
            ConnectionError::NetworkTimeout,
            ConnectionError::ConnectionRefused(rumqttc::ConnectReturnCode::NotAuthorized),
        ] {
            assert!(connect_went_out(&sent), "{sent}");
        }
    }

    #[test]
    fn the_packet_size_is_the_one_rumqttc_checks() {
        for payload_len in [
            0, 1, 100, 122, 123, 127, 128, 16_370, 16_383, 16_384, 300_000,
        ] {
            for qos in [QoS::AtMostOnce, QoS::AtLeastOnce] {
                let topic = "plant/gateway/gw1/stats/line-a";
                let mut publish = Publish::new(topic, qos, vec![0u8; payload_len]);
                // rumqttc numbers a QoS 1 publish before it measures and writes it.
                if qos != QoS::AtMostOnce {
                    publish.pkid = 1;
                }
                assert_eq!(
                    publish_packet_size(topic, payload_len, qos),
                    publish.size(),
                    "{payload_len} bytes at {qos:?}"
                );
            }
        }
    }

    #[test]
    fn a_publish_over_the_limit_is_refused_and_counted_on_every_connection() {
        let topic = "plant/gateway/gw1/stats";
        // The largest payload that fits (the remaining length's own bytes grow with it).
        let fits = (0..MAX_OUTGOING_PACKET)
            .rev()
            .find(|len| publish_packet_size(topic, *len, QoS::AtLeastOnce) <= MAX_OUTGOING_PACKET)
            .unwrap_or(0);
        assert_eq!(
            publish_packet_size(topic, fits, QoS::AtLeastOnce),
            MAX_OUTGOING_PACKET
        );
        let mut plain = PacketLimit::new(MAX_OUTGOING_PACKET, "plain");
        let mut node = plain.for_connection("sparkplug", MAX_OUTGOING_PACKET);
        assert!(plain.admits(topic, fits, QoS::AtLeastOnce));
        assert!(!plain.admits(topic, fits + 1, QoS::AtLeastOnce));
        assert!(!plain.admits(topic, fits + 1, QoS::AtLeastOnce));
        assert!(!node.admits("spBv1.0/plant/NBIRTH/gw1", fits * 2, QoS::AtMostOnce));
        assert_eq!(plain.refused(), 3);
        assert_eq!(node.refused(), 3);
        // Each topic is named in the log once.
        assert_eq!(plain.logged.len(), 1);
        assert_eq!(node.logged.len(), 1);
    }

    #[test]
    fn backoff_grows_to_its_cap_and_resets() {
        let mut backoff = Backoff::default();
        let mut previous_base = Duration::ZERO;
        for _ in 0..20 {
            let wait = backoff.next_wait();
            assert!(wait <= BACKOFF_MAX);
            assert!(wait >= BACKOFF_INITIAL.mul_f64(0.8));
            previous_base = previous_base.max(wait);
        }
        assert!(previous_base >= BACKOFF_MAX.mul_f64(0.8));
        backoff.reset();
        assert!(backoff.next_wait() <= BACKOFF_INITIAL.mul_f64(1.2));
    }

    #[test]
    fn connections_dying_young_in_a_row_are_reported_once() {
        let mut watch = ClashWatch::default();
        let young = Duration::from_millis(300);
        assert!(!watch.connection_ended(young));
        assert!(!watch.connection_ended(STABLE_CONNECTION));
        assert!(!watch.connection_ended(young));
        assert!(!watch.connection_ended(young));
        assert!(watch.connection_ended(young));
        assert!(!watch.connection_ended(young));
    }

    /// `TCP_NODELAY` of this process's own socket whose local address is `local`, read back
    /// from the kernel (every fd under /proc/self/fd that is a socket is asked its name).
    fn nodelay_of_own_socket(local: std::net::SocketAddr) -> Option<bool> {
        use std::os::fd::RawFd;
        let std::net::SocketAddr::V4(local) = local else {
            return None;
        };
        for entry in std::fs::read_dir("/proc/self/fd").ok()?.flatten() {
            let Ok(fd) = entry.file_name().to_string_lossy().parse::<RawFd>() else {
                continue;
            };
            let mut name: libc::sockaddr_in = unsafe { std::mem::zeroed() };
            let mut len = std::mem::size_of::<libc::sockaddr_in>() as libc::socklen_t;
            // SAFETY: `name` and `len` are valid for writes of `len` bytes; a fd that is not a
            // socket (or closed meanwhile) only makes the call fail.
            let named =
                unsafe { libc::getsockname(fd, std::ptr::addr_of_mut!(name).cast(), &mut len) };
            if named != 0
                || i32::from(name.sin_family) != libc::AF_INET
                || u16::from_be(name.sin_port) != local.port()
                || u32::from_be(name.sin_addr.s_addr) != u32::from(*local.ip())
            {
                continue;
            }
            let mut value: libc::c_int = 0;
            let mut len = std::mem::size_of::<libc::c_int>() as libc::socklen_t;
            // SAFETY: `value` and `len` are valid for writes of `len` bytes.
            let read = unsafe {
                libc::getsockopt(
                    fd,
                    libc::IPPROTO_TCP,
                    libc::TCP_NODELAY,
                    std::ptr::addr_of_mut!(value).cast(),
                    &mut len,
                )
            };
            return (read == 0).then_some(value != 0);
        }
        None
    }

    #[tokio::test]
    async fn the_client_socket_sends_without_nagle() {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let port = listener.local_addr().unwrap().port();
        let (_client, mut eventloop) =
            client(MqttOptions::new("nodelay-probe", "127.0.0.1", port), 8);
        // The loop connects and then waits for a CONNACK that never comes; meanwhile the
        // accepted end names the client's socket (which lives as long as the pending poll).
        let poll = eventloop.poll();
        tokio::pin!(poll);
        let (_server_end, client_socket) = tokio::select! {
            accepted = listener.accept() => accepted.unwrap(),
            polled = &mut poll => panic!("the event loop ended first: {polled:?}"),
        };
        assert_eq!(nodelay_of_own_socket(client_socket), Some(true));
    }
}
