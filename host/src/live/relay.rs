//! The public side of the live server: a TCP relay in front of the SDK's WebSocket server that
//! gives each client a bounded queue of its own.
//!
//! Towards the server the client's bytes pass unchanged (its HTTP upgrade, its requests). From
//! the server, after the HTTP response, the stream is cut into WebSocket frames (RFC 6455 §5.2;
//! a server's frames are not masked) and queued for the client. The relay reads the server as
//! fast as it writes, so the SDK's own queues never fill; when a client's queue holds more than
//! its budget, Message Data frames (binary, opcode 0x01 of the Foxglove protocol) are dropped and
//! counted: the oldest of the same subscription as the newcomer (an old camera frame for a new
//! one, so that a flood of frames does not push out the rare status or trial outcome), else the
//! oldest of any. Everything else (server info, advertisements, statuses) always goes through.
//! A client that disconnects ends its relay; the server sees it leave.
use std::collections::VecDeque;
use std::io::{self, BufRead, BufReader, Read, Write};
use std::net::{Shutdown, SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex};

/// What one client may have queued before its oldest message data is dropped (about fifty
/// camera frames of the sim).
pub const CLIENT_QUEUE_BYTES: usize = 4 << 20;

/// The largest frame taken from the server; a longer one ends the connection.
const MAX_FRAME: u64 = 1 << 30;

#[derive(Default)]
struct Shared {
    stopping: AtomicBool,
    clients_total: AtomicU64,
    dropped: AtomicU64,
    active: Mutex<Vec<(u64, TcpStream)>>,
    idle: Condvar,
}

/// A running relay: its listening thread and the clients it serves.
pub struct Relay {
    addr: SocketAddr,
    shared: Arc<Shared>,
    accept: Mutex<Option<std::thread::JoinHandle<()>>>,
}

impl Relay {
    /// Listens at `public` and relays each client to `upstream`.
    pub fn start(public: SocketAddr, upstream: SocketAddr, budget: usize) -> io::Result<Relay> {
        let listener = TcpListener::bind(public)?;
        let addr = listener.local_addr()?;
        let shared = Arc::new(Shared::default());
        let s = shared.clone();
        let accept = std::thread::Builder::new().name("live-accept".into()).spawn(move || {
            for conn in listener.incoming() {
                if s.stopping.load(Ordering::SeqCst) {
                    return;
                }
                let Ok(client) = conn else { continue };
                let s = s.clone();
                // Each client on threads of its own; a failure ends only that client.
                let _ = std::thread::Builder::new().name("live-client".into()).spawn(move || {
                    let _ = serve(client, upstream, budget, &s);
                });
            }
        })?;
        Ok(Relay { addr, shared, accept: Mutex::new(Some(accept)) })
    }

    /// The address clients connect to (the port chosen when 0 was asked for).
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// Clients that have connected since the start.
    pub fn clients_total(&self) -> u64 {
        self.shared.clients_total.load(Ordering::SeqCst)
    }

    /// Message Data frames dropped from slow clients' queues, all clients together.
    pub fn dropped(&self) -> u64 {
        self.shared.dropped.load(Ordering::SeqCst)
    }

    /// Clients connected now.
    pub fn active(&self) -> usize {
        self.shared.active.lock().unwrap_or_else(|e| e.into_inner()).len()
    }

    /// Blocks until no client is connected.
    pub fn wait_idle(&self) {
        let mut a = self.shared.active.lock().unwrap_or_else(|e| e.into_inner());
        while !a.is_empty() {
            a = self.shared.idle.wait(a).unwrap_or_else(|e| e.into_inner());
        }
    }

    /// Stops accepting and disconnects every client.
    pub fn stop(&self) {
        let Some(accept) = self.accept.lock().unwrap_or_else(|e| e.into_inner()).take() else { return };
        self.shared.stopping.store(true, Ordering::SeqCst);
        // Wake the accepting thread (a wildcard address is reached on loopback).
        let mut wake = self.addr;
        if wake.ip().is_unspecified() {
            wake.set_ip(if wake.is_ipv4() { [127, 0, 0, 1].into() } else { std::net::Ipv6Addr::LOCALHOST.into() });
        }
        let _ = TcpStream::connect(wake);
        let _ = accept.join();
        for (_, c) in self.shared.active.lock().unwrap_or_else(|e| e.into_inner()).iter() {
            let _ = c.shutdown(Shutdown::Both);
        }
    }
}

/// One queued piece of the server's output.
struct Item {
    bytes: Vec<u8>,
    /// Message Data, and its subscription id: may be dropped.
    data_of: Option<u32>,
}

impl Item {
    fn control(bytes: Vec<u8>) -> Item {
        Item { bytes, data_of: None }
    }
}

#[derive(Default)]
struct Queue {
    items: VecDeque<Item>,
    bytes: usize,
    closed: bool,
}

struct Outbox {
    q: Mutex<Queue>,
    cv: Condvar,
    budget: usize,
}

impl Outbox {
    /// Queues `item`; over the budget, drops message data, the oldest of `item`'s subscription
    /// first, then the oldest of any (or `item` itself when nothing older can go). Returns how
    /// many were dropped.
    fn push(&self, item: Item) -> u64 {
        let mut q = self.q.lock().unwrap_or_else(|e| e.into_inner());
        let mut dropped = 0;
        while q.bytes + item.bytes.len() > self.budget {
            let same = item.data_of.and_then(|s| q.items.iter().position(|i| i.data_of == Some(s)));
            match same.or_else(|| q.items.iter().position(|i| i.data_of.is_some())) {
                Some(k) => {
                    let old = q.items.remove(k).expect("found above");
                    q.bytes -= old.bytes.len();
                    dropped += 1;
                }
                None => break,
            }
        }
        if item.data_of.is_some() && q.bytes + item.bytes.len() > self.budget && !q.items.is_empty() {
            return dropped + 1;
        }
        q.bytes += item.bytes.len();
        q.items.push_back(item);
        self.cv.notify_one();
        dropped
    }

    fn close(&self) {
        self.q.lock().unwrap_or_else(|e| e.into_inner()).closed = true;
        self.cv.notify_all();
    }

    /// The next item; `None` once closed and empty.
    fn pop(&self) -> Option<Item> {
        let mut q = self.q.lock().unwrap_or_else(|e| e.into_inner());
        loop {
            if let Some(i) = q.items.pop_front() {
                q.bytes -= i.bytes.len();
                return Some(i);
            }
            if q.closed {
                return None;
            }
            q = self.cv.wait(q).unwrap_or_else(|e| e.into_inner());
        }
    }
}

fn serve(client: TcpStream, upstream: SocketAddr, budget: usize, s: &Arc<Shared>) -> io::Result<()> {
    let server = TcpStream::connect(upstream)?;
    let _ = client.set_nodelay(true);
    let _ = server.set_nodelay(true);
    let id = s.clients_total.fetch_add(1, Ordering::SeqCst);
    s.active.lock().unwrap_or_else(|e| e.into_inner()).push((id, client.try_clone()?));
    let outbox = Arc::new(Outbox { q: Mutex::new(Queue::default()), cv: Condvar::new(), budget });
    // Client to server, unchanged.
    let up = {
        let (mut from, mut to) = (client.try_clone()?, server.try_clone()?);
        std::thread::Builder::new().name("live-up".into()).spawn(move || {
            let _ = io::copy(&mut from, &mut to);
            let _ = to.shutdown(Shutdown::Write);
        })?
    };
    // Server to the queue.
    let down = {
        let (from, ob, sh) = (server.try_clone()?, outbox.clone(), s.clone());
        std::thread::Builder::new().name("live-down".into()).spawn(move || {
            let _ = read_server(from, &ob, &sh);
            ob.close();
        })?
    };
    // The queue to the client, on this thread.
    let mut to = client.try_clone()?;
    while let Some(item) = outbox.pop() {
        if to.write_all(&item.bytes).is_err() {
            break;
        }
    }
    // Either side gone: end both.
    let _ = client.shutdown(Shutdown::Both);
    let _ = server.shutdown(Shutdown::Both);
    outbox.close();
    let _ = up.join();
    let _ = down.join();
    let mut a = s.active.lock().unwrap_or_else(|e| e.into_inner());
    a.retain(|(i, _)| *i != id);
    s.idle.notify_all();
    Ok(())
}

/// Reads the server's HTTP response, then its frames, into `ob`.
fn read_server(server: TcpStream, ob: &Outbox, s: &Shared) -> io::Result<()> {
    let mut r = BufReader::new(server);
    let mut head = Vec::new();
    loop {
        let n = r.read_until(b'\n', &mut head)?;
        if n == 0 {
            return Ok(());
        }
        if head.ends_with(b"\r\n\r\n") || head == b"\r\n" {
            break;
        }
    }
    let upgraded = head.starts_with(b"HTTP/1.1 101");
    ob.push(Item::control(head));
    if !upgraded {
        // A refused handshake: the rest (an error body) as it comes.
        let mut buf = vec![0; 16 << 10];
        loop {
            let n = r.read(&mut buf)?;
            if n == 0 {
                return Ok(());
            }
            ob.push(Item::control(buf[..n].to_vec()));
        }
    }
    loop {
        let Some(frame) = read_frame(&mut r)? else { return Ok(()) };
        let dropped = ob.push(frame);
        if dropped > 0 {
            s.dropped.fetch_add(dropped, Ordering::SeqCst);
        }
    }
}

/// One whole WebSocket frame, as read; `None` at a clean end between frames.
fn read_frame(r: &mut impl Read) -> io::Result<Option<Item>> {
    let mut h = [0u8; 2];
    match r.read(&mut h[..1])? {
        0 => return Ok(None),
        _ => r.read_exact(&mut h[1..])?,
    }
    let mut bytes = h.to_vec();
    let len = match h[1] & 0x7f {
        126 => {
            let mut b = [0u8; 2];
            r.read_exact(&mut b)?;
            bytes.extend(b);
            u16::from_be_bytes(b) as u64
        }
        127 => {
            let mut b = [0u8; 8];
            r.read_exact(&mut b)?;
            bytes.extend(b);
            u64::from_be_bytes(b)
        }
        n => n as u64,
    };
    let masked = h[1] & 0x80 != 0;
    if masked {
        let mut m = [0u8; 4];
        r.read_exact(&mut m)?;
        bytes.extend(m);
    }
    if len > MAX_FRAME {
        return Err(io::Error::new(io::ErrorKind::InvalidData, format!("a frame of {len} bytes")));
    }
    let start = bytes.len();
    bytes.resize(start + len as usize, 0);
    r.read_exact(&mut bytes[start..])?;
    let (fin, opcode) = (h[0] & 0x80 != 0, h[0] & 0x0f);
    // Whole binary messages whose first byte is Message Data (then the subscription id, u32
    // little-endian); never a fragment.
    let p = &bytes[start..];
    let data_of = (fin && opcode == 0x2 && !masked && p.len() >= 5 && p[0] == 0x01)
        .then(|| u32::from_le_bytes([p[1], p[2], p[3], p[4]]));
    Ok(Some(Item { bytes, data_of }))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(opcode: u8, payload: &[u8]) -> Vec<u8> {
        let mut f = vec![0x80 | opcode];
        match payload.len() {
            n if n < 126 => f.push(n as u8),
            n if n < 65536 => {
                f.push(126);
                f.extend((n as u16).to_be_bytes());
            }
            n => {
                f.push(127);
                f.extend((n as u64).to_be_bytes());
            }
        }
        f.extend(payload);
        f
    }

    /// RFC 6455 §5.7's examples: an unmasked "Hello", and a 256-byte and a 64 KiB binary
    /// message (16- and 64-bit lengths).
    #[test]
    fn frames_are_cut_at_their_lengths() {
        let mut s = vec![0x81, 0x05, 0x48, 0x65, 0x6c, 0x6c, 0x6f];
        s.extend([0x82, 0x7E, 0x01, 0x00]);
        s.extend([0x01; 256]);
        s.extend([0x82, 0x7F, 0, 0, 0, 0, 0, 1, 0, 0]);
        s.extend(vec![0x02; 65536]);
        let mut r = &s[..];
        let a = read_frame(&mut r).unwrap().unwrap();
        assert_eq!(a.bytes, b"\x81\x05Hello");
        assert_eq!(a.data_of, None, "text");
        let b = read_frame(&mut r).unwrap().unwrap();
        assert_eq!(b.bytes.len(), 4 + 256);
        assert_eq!(b.data_of, Some(0x0101_0101), "binary, opcode 0x01: message data");
        let c = read_frame(&mut r).unwrap().unwrap();
        assert_eq!(c.bytes.len(), 10 + 65536);
        assert_eq!(c.data_of, None, "binary, opcode 0x02: time");
        assert!(read_frame(&mut r).unwrap().is_none());
        let mut cut = &frame(2, &[1; 300])[..100];
        assert!(read_frame(&mut cut).is_err(), "a cut frame is an error");
    }

    #[test]
    fn over_budget_the_oldest_message_data_goes_and_control_stays() {
        let ob = Outbox { q: Mutex::new(Queue::default()), cv: Condvar::new(), budget: 1000 };
        let data = |k: u8, sub: u32| Item { bytes: vec![k; 300], data_of: Some(sub) };
        assert_eq!(ob.push(Item::control(vec![0; 100])), 0);
        assert_eq!(ob.push(data(1, 7)), 0);
        assert_eq!(ob.push(data(2, 8)), 0);
        assert_eq!(ob.push(data(3, 8)), 0);
        assert_eq!(ob.push(data(4, 8)), 1, "the oldest of subscription 8 goes, not the older 7");
        assert_eq!(ob.push(data(5, 9)), 1, "none of 9 queued: the oldest of any");
        assert_eq!(ob.push(Item::control(vec![6; 600])), 2, "control always goes in");
        ob.close();
        let got: Vec<u8> = std::iter::from_fn(|| ob.pop()).map(|i| i.bytes[0]).collect();
        assert_eq!(got, [0, 5, 6]);
    }
}
