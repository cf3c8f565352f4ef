"""Reads an MCAP file that msr wrote with two implementations independent of msr's:

- `rosbags` (AnyReader with the file's own message definitions, no built-in types) decodes every
  message with its own CDR decoder;
- the `mcap` package checks the summary (statistics, chunk indexes, one channel a topic) and reads
  the messages again through the index.

Prints one JSON object: per topic its type and count, the images (sizes, encodings; with --dump DIR
each /camera/image's bytes go to DIR/camera_NNNN.raw), the joint states, the annotations and what
the summary says. Exits non-zero when the two readers disagree or the index is missing.

usage: read_mcap.py FILE [--dump DIR]
"""
import argparse
import json
import sys
from collections import Counter
from pathlib import Path

from mcap.reader import make_reader
from rosbags.highlevel import AnyReader


def fail(msg):
    print(msg, file=sys.stderr)
    sys.exit(1)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument('file')
    ap.add_argument('--dump')
    a = ap.parse_args()
    path = Path(a.file)
    out = {'topics': {}, 'images': [], 'joints': [], 'annotations': [], 'status': [], 'trials': []}
    dump = Path(a.dump) if a.dump else None
    if dump:
        dump.mkdir(parents=True, exist_ok=True)
    n_camera = 0
    with AnyReader([path]) as r:
        for c in r.connections:
            out['topics'][c.topic] = {'type': c.msgtype, 'count': c.msgcount}
        decoded = Counter()
        for c, t, raw in r.messages():
            m = r.deserialize(raw, c.msgtype)
            decoded[c.topic] += 1
            if c.msgtype == 'sensor_msgs/msg/Image':
                stamp = m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
                out['images'].append({'topic': c.topic, 't': t, 'stamp': stamp, 'width': m.width,
                                      'height': m.height, 'encoding': m.encoding, 'step': m.step,
                                      'bytes': len(m.data)})
                if dump and c.topic == '/camera/image':
                    (dump / f'camera_{n_camera:04}.raw').write_bytes(bytes(m.data))
                    n_camera += 1
            elif c.msgtype == 'sensor_msgs/msg/JointState':
                out['joints'].append({'topic': c.topic, 't': t, 'name': list(m.name),
                                      'position': [float(x) for x in m.position]})
            elif c.msgtype == 'foxglove_msgs/msg/ImageAnnotations':
                stamps = {p.timestamp.sec * 10**9 + p.timestamp.nanosec for p in m.points}
                out['annotations'].append({'t': t, 'points': [len(p.points) for p in m.points],
                                           'circles': [[c.position.x, c.position.y] for c in m.circles],
                                           'texts': [x.text for x in m.texts], 'stamps': sorted(stamps)})
            elif c.msgtype == 'diagnostic_msgs/msg/DiagnosticArray':
                kv = {v.key: v.value for s in m.status for v in s.values}
                key = 'trials' if c.topic == '/msr/trial' else 'status'
                out[key].append({'t': t, 'name': m.status[0].name if m.status else '', 'values': kv})
        for topic, info in out['topics'].items():
            if decoded[topic] != info['count']:
                fail(f'rosbags: {topic} has {info["count"]} messages by the summary, decoded {decoded[topic]}')

    with open(path, 'rb') as f:
        reader = make_reader(f)
        header = reader.get_header()
        summary = reader.get_summary()
        if summary is None or summary.statistics is None:
            fail('mcap: no summary or no statistics')
        if not summary.chunk_indexes:
            fail('mcap: no chunk indexes')
        topics = Counter(ch.topic for ch in summary.channels.values())
        if any(n > 1 for n in topics.values()):
            fail(f'mcap: a topic has several channels: {topics}')
        by_channel = summary.statistics.channel_message_counts
        stats = {summary.channels[cid].topic: n for cid, n in by_channel.items()}
        seen = Counter()
        last = {}
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            seen[channel.topic] += 1
            if schema.encoding != 'ros2msg' or channel.message_encoding != 'cdr':
                fail(f'mcap: {channel.topic} is {schema.encoding}/{channel.message_encoding}')
            if message.log_time < last.get(channel.topic, 0):
                fail(f'mcap: {channel.topic} out of time order')
            last[channel.topic] = message.log_time
        if dict(seen) != stats:
            fail(f'mcap: indexed read {dict(seen)} differs from the statistics {stats}')
        if stats != {k: v['count'] for k, v in out['topics'].items()}:
            fail(f'mcap statistics {stats} and rosbags counts differ')
        out['mcap'] = {'profile': header.profile, 'library': header.library,
                       'message_count': summary.statistics.message_count,
                       'chunks': len(summary.chunk_indexes),
                       'compression': sorted({c.compression for c in summary.chunk_indexes}),
                       'message_index_offsets': sum(len(c.message_index_offsets) for c in summary.chunk_indexes)}
    print(json.dumps(out))


if __name__ == '__main__':
    main()
