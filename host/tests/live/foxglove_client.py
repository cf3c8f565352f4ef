"""A Foxglove WebSocket protocol client written from the published specifications, not from any
server's code: RFC 6455 (the WebSocket handshake and framing) and foxglove/ws-protocol
docs/spec.md (serverInfo, advertise, subscribe; binary Message Data: opcode 0x01, uint32
subscription id, uint64 receive time, payload, little-endian). Messages are decoded with the
Python `rosbags` package from the ros2msg schema text each channel advertises (a typestore of its
own per channel, no built-in types), CDR by rosbags' own decoder.

usage: foxglove_client.py HOST:PORT MODE
  full   subscribe to every channel; read until each has decoded a message (a second client,
         on a thread of its own, connects once the first has seen 3 camera frames: it must get
         the channels and the next frames); print a JSON report; disconnect. A line `end` on
         standard input (the session is over) makes both stop once the server falls silent,
         so that a missing message fails the test rather than hanging it
  slow   subscribe to every channel with a small receive buffer, then never read again; stay
         connected until standard input closes
"""
import select
import base64
import hashlib
import json
import os
import socket
import struct
import sys
import threading

from rosbags.typesys import Stores, get_types_from_msg, get_typestore

GUID = b'258EAFA5-E914-47DA-95CA-C5AB0DC85B11'  # RFC 6455 section 1.3
SUBPROTOCOL = 'foxglove.sdk.v1'


class Ws:
    def __init__(self, addr, rcvbuf=None):
        host, port = addr.rsplit(':', 1)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        if rcvbuf:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
        self.sock.connect((host, int(port)))
        self.buf = b''
        key = base64.b64encode(os.urandom(16))
        req = (f'GET / HTTP/1.1\r\nHost: {addr}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n'
               f'Sec-WebSocket-Key: {key.decode()}\r\nSec-WebSocket-Version: 13\r\n'
               f'Sec-WebSocket-Protocol: {SUBPROTOCOL}\r\n\r\n')
        self.sock.sendall(req.encode())
        head = self._until(b'\r\n\r\n').decode('latin-1')
        lines = head.split('\r\n')
        if not lines[0].startswith('HTTP/1.1 101'):
            raise SystemExit(f'handshake refused: {lines[0]}')
        fields = {k.strip().lower(): v.strip() for k, v in (l.split(':', 1) for l in lines[1:] if ':' in l)}
        want = base64.b64encode(hashlib.sha1(key + GUID).digest()).decode()
        if fields.get('sec-websocket-accept') != want:
            raise SystemExit(f'bad Sec-WebSocket-Accept: {fields}')
        self.protocol = fields.get('sec-websocket-protocol')
        if self.protocol != SUBPROTOCOL:
            raise SystemExit(f'server chose subprotocol {self.protocol!r}')

    def _until(self, end):
        while end not in self.buf:
            chunk = self.sock.recv(65536)
            if not chunk:
                raise EOFError('closed during the handshake')
            self.buf += chunk
        i = self.buf.index(end) + len(end)
        out, self.buf = self.buf[:i], self.buf[i:]
        return out

    def _exact(self, n):
        while len(self.buf) < n:
            chunk = self.sock.recv(max(65536, n - len(self.buf)))
            if not chunk:
                raise EOFError('connection closed')
            self.buf += chunk
        out, self.buf = self.buf[:n], self.buf[n:]
        return out

    def send(self, opcode, payload):
        # A client masks every frame (RFC 6455 section 5.3).
        n = len(payload)
        head = bytes([0x80 | opcode])
        if n < 126:
            head += bytes([0x80 | n])
        elif n < 65536:
            head += bytes([0x80 | 126]) + struct.pack('>H', n)
        else:
            head += bytes([0x80 | 127]) + struct.pack('>Q', n)
        mask = os.urandom(4)
        body = bytes(b ^ mask[i % 4] for i, b in enumerate(payload))
        self.sock.sendall(head + mask + body)

    def send_json(self, obj):
        self.send(0x1, json.dumps(obj).encode())

    def recv(self):
        """The next whole message: (opcode, bytes); continuation frames joined, pings answered.
        None once the server closes."""
        parts, first = [], None
        while True:
            try:
                b0, b1 = self._exact(2)
            except EOFError:
                return None
            fin, opcode, n = b0 & 0x80, b0 & 0x0F, b1 & 0x7F
            if n == 126:
                n = struct.unpack('>H', self._exact(2))[0]
            elif n == 127:
                n = struct.unpack('>Q', self._exact(8))[0]
            mask = self._exact(4) if b1 & 0x80 else None
            data = self._exact(n)
            if mask:
                data = bytes(b ^ mask[i % 4] for i, b in enumerate(data))
            if opcode == 0x8:
                return None
            if opcode == 0x9:
                self.send(0xA, data)
                continue
            if opcode == 0xA:
                continue
            if opcode != 0x0:
                first = opcode
            parts.append(data)
            if fin:
                return first, b''.join(parts)

    def close(self):
        try:
            self.send(0x8, struct.pack('>H', 1000))
        except OSError:
            pass
        self.sock.close()


class Session:
    """One client: the server's info and channels, its subscriptions, decoded messages."""

    def __init__(self, addr, rcvbuf=None, ended=None):
        self.ws = Ws(addr, rcvbuf)
        self.ended = ended or threading.Event()
        self.advertised = False
        self.server_info = None
        self.channels = {}  # id -> advertised channel
        self.stores = {}
        self.subs = {}  # subscription id -> channel id
        self.counts = {}
        self.decoded = {}
        self.samples = {}
        self.first_stamp = {}
        self.stamps = {}

    def handle_text(self, m):
        if m['op'] == 'serverInfo':
            self.server_info = m
        elif m['op'] == 'advertise':
            self.advertised = True
            for c in m['channels']:
                self.channels[c['id']] = c

    def until_advertised(self, topics):
        while not (self.server_info and self.advertised and topics <= {c['topic'] for c in self.channels.values()}):
            m = self.ws.recv()
            if m is None:
                raise SystemExit('closed before the advertisements')
            if m[0] == 0x1:
                self.handle_text(json.loads(m[1]))

    def subscribe(self, topics=None):
        subs = []
        for cid, c in sorted(self.channels.items()):
            if topics is None or c['topic'] in topics:
                sid = len(self.subs) + 1
                self.subs[sid] = cid
                subs.append({'id': sid, 'channelId': cid})
        self.ws.send_json({'op': 'subscribe', 'subscriptions': subs})

    def decode(self, cid, payload):
        c = self.channels[cid]
        if c['encoding'] != 'cdr' or c.get('schemaEncoding') != 'ros2msg':
            raise SystemExit(f'{c["topic"]}: {c["encoding"]}/{c.get("schemaEncoding")}')
        if cid not in self.stores:
            store = get_typestore(Stores.EMPTY)
            store.register(get_types_from_msg(c['schema'], c['schemaName']))
            self.stores[cid] = store
        return self.stores[cid].deserialize_cdr(payload, c['schemaName'])

    def step(self):
        """Reads one message; False once the server closed, or fell silent after the end."""
        if not self.ws.buf and not select.select([self.ws.sock], [], [], 1.0)[0]:
            return not self.ended.is_set()
        m = self.ws.recv()
        if m is None:
            return False
        op, data = m
        if op == 0x1:
            self.handle_text(json.loads(data))
        elif op == 0x2 and data[0] == 0x01:
            sid, t = struct.unpack_from('<IQ', data, 1)
            cid = self.subs[sid]
            topic = self.channels[cid]['topic']
            self.counts[topic] = self.counts.get(topic, 0) + 1
            # A few of each decoded (and every camera frame, for its stamp): a client that keeps
            # up is not the one whose drops are tested.
            if self.counts[topic] > 3 and topic != '/camera/image':
                return True
            msg = self.decode(cid, data[13:])
            self.decoded[topic] = self.decoded.get(topic, 0) + 1
            self.samples[topic] = describe(msg)
            stamp = stamp_of(msg)
            if stamp is not None:
                self.first_stamp.setdefault(topic, stamp)
                self.stamps.setdefault(topic, []).append(stamp)
        return True

    def report(self):
        return {'protocol': self.ws.protocol, 'server_info': self.server_info,
                'channels': sorted(({k: c[k] for k in ('topic', 'encoding', 'schemaName', 'schemaEncoding')}
                                    for c in self.channels.values()), key=lambda c: c['topic']),
                'counts': self.counts, 'decoded': self.decoded, 'samples': self.samples}


def stamp_of(msg):
    h = getattr(msg, 'header', None)
    return h.stamp.sec * 10**9 + h.stamp.nanosec if h is not None else None


def describe(m):
    """A few decoded fields of a message, enough to check it means what its topic says."""
    name = type(m).__name__
    if hasattr(m, 'encoding') and hasattr(m, 'data'):
        return {'width': m.width, 'height': m.height, 'encoding': m.encoding, 'step': m.step, 'bytes': len(m.data)}
    if hasattr(m, 'position') and hasattr(m, 'name'):
        return {'name': list(m.name), 'position': [float(x) for x in m.position]}
    if hasattr(m, 'circles'):
        return {'points': [len(p.points) for p in m.points], 'texts': [t.text for t in m.texts]}
    if hasattr(m, 'status'):
        return {'names': [s.name for s in m.status], 'keys': [v.key for s in m.status for v in s.values]}
    return {'type': name}


def full(addr):
    ended = threading.Event()

    def watch_stdin():
        for line in sys.stdin:
            if line.strip() == 'end':
                break
        ended.set()

    threading.Thread(target=watch_stdin, daemon=True).start()
    first = Session(addr, ended=ended)
    first.until_advertised(set())
    first.subscribe()
    topics = {c['topic'] for c in first.channels.values()}
    second_report = {}
    second_started = threading.Event()

    def second():
        s = Session(addr, ended=ended)
        s.until_advertised(topics)
        s.subscribe({'/camera/image'})
        # The latched frame first, then the next ones: two frames of later stamps than the first.
        while len(s.stamps.get('/camera/image', [])) < 3:
            if not s.step():
                break
        second_report.update(s.report())
        second_report['camera_stamps'] = s.stamps.get('/camera/image', [])
        s.ws.close()

    t = threading.Thread(target=second)
    while set(first.counts) != topics or t.is_alive() or not second_started.is_set():
        if not second_started.is_set() and first.counts.get('/camera/image', 0) >= 3:
            second_started.set()
            t.start()
        if not first.step():
            break
    if second_started.is_set():
        t.join()
    out = first.report()
    out['second'] = second_report
    out['camera_stamps_before_second'] = first.stamps.get('/camera/image', [])[:3]
    print(json.dumps(out))
    first.ws.close()


def slow(addr):
    s = Session(addr, rcvbuf=4096)
    s.until_advertised(set())
    s.subscribe()
    print(json.dumps({'subscribed': len(s.subs)}), flush=True)
    # Never read again: wait for standard input to close.
    sys.stdin.read()
    s.ws.close()


if __name__ == '__main__':
    {'full': full, 'slow': slow}[sys.argv[2]](sys.argv[1])
