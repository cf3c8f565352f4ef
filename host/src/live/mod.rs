//! A live view: a session's messages served as they happen over the Foxglove WebSocket
//! protocol, for the Foxglove app to connect to. The channels are the topics, types and `ros2msg`
//! schemas of a session's MCAP file ([`crate::rosbag::session`]), messages in CDR, so a layout
//! made for a recording works live.
//!
//! Foxglove's SDK (`foxglove`, its WebSocket server) speaks the protocol on a private loopback
//! port; clients connect to [`relay`] at the public address, which passes the bytes through
//! and holds what goes out to each client in a queue of its own. A client that reads too slowly
//! has its oldest message data dropped there, and counted (the SDK drops on its own queues too,
//! but does not say how many). Publishing never waits on a client: it is a queue push.
//!
//! A client that subscribes gets the channel's latest message at once (the state is latched),
//! then every message after it, each once: a message goes only to the clients whose
//! subscription the listener has seen (the SDK subscribes a client's sink before it tells the
//! listener, so a message logged to every sink between the two would reach a new client live
//! and then again as the latched one).
pub mod relay;

use crate::rosbag::msgs;
use anyhow::{anyhow, Context as _, Result};
use foxglove::websocket::{ChannelView, Client, ServerListener};
use foxglove::{ChannelId, Context, RawChannel, Schema, SinkId, WebSocketServer, WebSocketServerHandle};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::{Arc, Condvar, Mutex};

/// Where `--live` listens when it names no address.
pub const DEFAULT_ADDR: &str = "127.0.0.1:8765";

/// The topics a session publishes and their types (the table in [`crate::rosbag::session`]).
pub const TOPICS: [(&str, &str); 11] = [
    ("/camera/image", msgs::IMAGE),
    ("/face/image", msgs::IMAGE),
    ("/face/predicted", msgs::IMAGE),
    ("/face/saliency", msgs::IMAGE),
    ("/camera/annotations", msgs::IMAGE_ANNOTATIONS),
    ("/joint_states", msgs::JOINT_STATE),
    ("/joint_commands", msgs::JOINT_STATE),
    ("/board/head", msgs::JOINT_STATE),
    ("/reach/target", msgs::JOINT_STATE),
    ("/board/status", msgs::DIAGNOSTIC_ARRAY),
    ("/msr/trial", msgs::DIAGNOSTIC_ARRAY),
];

/// What a live session served, for the run's summary.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct LiveStats {
    /// Clients that connected over the run.
    pub clients: u64,
    /// Messages published.
    pub messages: u64,
    /// Messages dropped for clients that read too slowly (each client's drops counted).
    pub dropped: u64,
}

impl std::fmt::Display for LiveStats {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "live: {} clients, {} messages published, {} dropped for slow clients",
            self.clients, self.messages, self.dropped
        )
    }
}

/// Per channel: the latest message and the sinks that have been given it.
struct Latched {
    channel: Arc<RawChannel>,
    latest: Option<Vec<u8>>,
    sinks: Vec<SinkId>,
}

/// Every channel's latch, and whether any client has subscribed yet.
#[derive(Default)]
struct Latch {
    channels: HashMap<ChannelId, Latched>,
    subscribed: bool,
}

struct Listener(Arc<(Mutex<Latch>, Condvar)>);

impl ServerListener for Listener {
    fn on_subscribe(&self, client: Client, channel: ChannelView) {
        let (latch, cv) = &*self.0;
        let mut l = latch.lock().unwrap_or_else(|e| e.into_inner());
        if let (Some(c), Some(sink)) = (l.channels.get_mut(&channel.id()), client.sink_id()) {
            if let Some(msg) = &c.latest {
                c.channel.log_to_sink(msg, Some(sink));
            }
            if !c.sinks.contains(&sink) {
                c.sinks.push(sink);
            }
        }
        l.subscribed = true;
        cv.notify_all();
    }

    fn on_unsubscribe(&self, client: Client, channel: ChannelView) {
        let mut l = self.0 .0.lock().unwrap_or_else(|e| e.into_inner());
        if let (Some(c), Some(sink)) = (l.channels.get_mut(&channel.id()), client.sink_id()) {
            c.sinks.retain(|s| *s != sink);
        }
    }
}

/// A running live server.
pub struct Live {
    /// Held: the SDK's channels and server refer to their context weakly.
    _ctx: Arc<Context>,
    addr: SocketAddr,
    by_topic: HashMap<&'static str, Arc<RawChannel>>,
    latch: Arc<(Mutex<Latch>, Condvar)>,
    server: Mutex<Option<WebSocketServerHandle>>,
    relay: relay::Relay,
    published: std::sync::atomic::AtomicU64,
}

impl std::fmt::Debug for Live {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Live(ws://{})", self.addr)
    }
}

/// One server is equal only to itself (configurations holding it compare by it).
impl PartialEq for Live {
    fn eq(&self, other: &Live) -> bool {
        std::ptr::eq(self, other)
    }
}

impl Live {
    /// Starts the server at `addr` (port 0: any free port) with every channel of [`TOPICS`]
    /// advertised.
    pub fn start(addr: SocketAddr) -> Result<Live> {
        let ctx = Context::new();
        let mut by_topic = HashMap::new();
        let mut latch = Latch::default();
        for (topic, ty) in TOPICS {
            let def = msgs::definition(ty).ok_or_else(|| anyhow!("no definition of {ty}"))?;
            let ch = ctx
                .channel_builder(topic)
                .message_encoding("cdr")
                .schema(Schema::new(ty, "ros2msg", def.into_bytes()))
                .build_raw()
                .map_err(|e| anyhow!("the live view: channel {topic}: {e}"))?;
            latch.channels.insert(ch.id(), Latched { channel: ch.clone(), latest: None, sinks: Vec::new() });
            by_topic.insert(topic, ch);
        }
        let latch = Arc::new((Mutex::new(latch), Condvar::new()));
        // The SDK's server on a private loopback port; clients come through the relay.
        let server = WebSocketServer::new()
            .context(&ctx)
            .name(concat!("msr ", env!("CARGO_PKG_VERSION")))
            .bind("127.0.0.1", 0)
            .listener(Arc::new(Listener(latch.clone())))
            .start_blocking()
            .map_err(|e| anyhow!("the live view: cannot start the Foxglove server: {e}"))?;
        let upstream = SocketAddr::from(([127, 0, 0, 1], server.port()));
        let relay = relay::Relay::start(addr, upstream, relay::CLIENT_QUEUE_BYTES)
            .with_context(|| format!("the live view at {addr}"))?;
        Ok(Live {
            _ctx: ctx,
            addr: relay.addr(),
            by_topic,
            latch,
            server: Mutex::new(Some(server)),
            relay,
            published: Default::default(),
        })
    }

    /// Where clients connect.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// The URL to give Foxglove.
    pub fn url(&self) -> String {
        format!("ws://{}", self.addr)
    }

    /// Publishes one CDR message (ROS 2 encapsulation header included) on `topic`; it becomes
    /// the channel's latest. A topic not in [`TOPICS`] is an error of the caller's.
    pub fn publish(&self, topic: &str, cdr: &[u8]) -> Result<()> {
        let ch = self.by_topic.get(topic).ok_or_else(|| anyhow!("the live view: no channel {topic}"))?;
        {
            let mut l = self.latch.0.lock().unwrap_or_else(|e| e.into_inner());
            // Under the latch: a client subscribing now gets either the latest or this one.
            if let Some(c) = l.channels.get_mut(&ch.id()) {
                c.latest = Some(cdr.to_vec());
                for sink in &c.sinks {
                    ch.log_to_sink(cdr, Some(*sink));
                }
            }
        }
        self.published.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        Ok(())
    }

    /// Blocks until some client has subscribed to a channel.
    pub fn wait_for_subscriber(&self) {
        let (latch, cv) = &*self.latch;
        let mut l = latch.lock().unwrap_or_else(|e| e.into_inner());
        while !l.subscribed {
            l = cv.wait(l).unwrap_or_else(|e| e.into_inner());
        }
    }

    /// Clients connected now.
    pub fn clients_now(&self) -> usize {
        self.relay.active()
    }

    /// Blocks until no client is connected.
    pub fn wait_for_no_clients(&self) {
        self.relay.wait_idle();
    }

    /// The figures so far: clients that connected, messages published, messages dropped.
    pub fn stats(&self) -> LiveStats {
        LiveStats {
            clients: self.relay.clients_total(),
            messages: self.published.load(std::sync::atomic::Ordering::Relaxed),
            dropped: self.relay.dropped(),
        }
    }

    /// Stops serving: the clients are disconnected. Returns the final figures.
    pub fn stop(&self) -> LiveStats {
        if let Some(s) = self.server.lock().unwrap_or_else(|e| e.into_inner()).take() {
            s.stop().wait_blocking();
        }
        self.relay.stop();
        self.stats()
    }
}

impl Drop for Live {
    fn drop(&mut self) {
        self.stop();
    }
}

/// Nanoseconds since the Unix epoch, now.
pub fn now_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}

/// Parses `--live`'s address.
pub fn parse_addr(s: &str) -> std::result::Result<SocketAddr, String> {
    use std::net::ToSocketAddrs;
    s.to_socket_addrs()
        .map_err(|e| format!("not an address and port ({e}), e.g. {DEFAULT_ADDR} or 0.0.0.0:8765"))?
        .next()
        .ok_or_else(|| format!("{s} names no address"))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The layout in docs/ names only channels the server advertises, images on Image panels.
    #[test]
    fn the_docs_layout_uses_the_channels() {
        let v: serde_json::Value = serde_json::from_str(include_str!("../../../docs/foxglove-layout.json")).unwrap();
        let ty = |t: &str| TOPICS.iter().find(|(n, _)| *n == t).map(|(_, ty)| *ty);
        let mut seen = 0;
        for (id, c) in v["configById"].as_object().unwrap() {
            if let Some(m) = c.get("imageMode") {
                assert_eq!(ty(m["imageTopic"].as_str().unwrap()), Some(msgs::IMAGE), "{id}");
                for a in m["annotations"].as_object().unwrap().keys() {
                    assert_eq!(ty(a), Some(msgs::IMAGE_ANNOTATIONS), "{id}");
                }
                seen += 1;
            }
            for p in c.get("paths").and_then(|p| p.as_array()).into_iter().flatten() {
                let topic = p["value"].as_str().unwrap().split('.').next().unwrap();
                assert_eq!(ty(topic), Some(msgs::JOINT_STATE), "{id}: {p}");
                seen += 1;
            }
            if let Some(t) = c.get("topicPath") {
                assert_eq!(ty(t.as_str().unwrap()), Some(msgs::DIAGNOSTIC_ARRAY), "{id}");
                seen += 1;
            }
        }
        assert!(seen >= 10, "{seen}");
        // Every panel placed in the layout tree is configured.
        fn leaves(n: &serde_json::Value, out: &mut Vec<String>) {
            match n {
                serde_json::Value::String(s) => out.push(s.clone()),
                n => {
                    leaves(&n["first"], out);
                    leaves(&n["second"], out);
                }
            }
        }
        let mut placed = Vec::new();
        leaves(&v["layout"], &mut placed);
        placed.sort();
        let mut configured: Vec<String> = v["configById"].as_object().unwrap().keys().cloned().collect();
        configured.sort();
        assert_eq!(placed, configured);
    }
}
