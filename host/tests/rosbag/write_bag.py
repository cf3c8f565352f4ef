"""Writes a rosbag2 recording of an `msr dataset` folder's frames with the `rosbags` package (an
implementation independent of msr's): camera images at --image-hz, joint states at --joint-hz.

The head holds each frame's pose from 30 ms (--hold-ms) before to 30 ms after the frame's stamp and moves
linearly to the next pose in between (so an image's stamp falls where the head is still), as a
robot babbling its head would. The joint states name more joints than the head, in another order,
as naoqi_driver publishes them.

usage: write_bag.py DATASET OUT --storage mcap|sqlite3 --encoding E [--split train|all]
       [--image-hz 10] [--joint-hz 50] [--names HeadYaw,HeadPitch] [--hold-ms 30]
       [--cut K:F ...] [--nan-ms A:B] [--short-positions N]
E: mono8, rgb8, bgr8, yuv422 (UYVY), yuyv, jpeg, png, or any other string (written as an Image
with that encoding and rgb8 bytes, for the bad-input tests).
Damage, for the bad-input tests: --cut K:F keeps the first F (0..1) of image K's compressed bytes;
--nan-ms A:B makes the head's joint states from A to B ms (inclusive) NaN; --short-positions N
gives joint state N one position fewer than names.
"""
import argparse
import io
import json
from pathlib import Path

import numpy as np
from PIL import Image as PilImage
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore


def grey(rgb):
    """OpenCV's RGB2GRAY in fixed point, as msr converts."""
    r, g, b = (rgb[..., i].astype(np.uint32) for i in range(3))
    return ((r * 9798 + g * 19235 + b * 3735 + (1 << 14)) >> 15).astype(np.uint8)


def yuv422(rgb, order):
    """Y from grey(); U and V (BT.601) averaged over each pixel pair. order: 'uyvy' or 'yuyv'."""
    y = grey(rgb)
    f = rgb.astype(np.float64)
    u = np.clip(128 - 0.168736 * f[..., 0] - 0.331264 * f[..., 1] + 0.5 * f[..., 2], 0, 255)
    v = np.clip(128 + 0.5 * f[..., 0] - 0.418688 * f[..., 1] - 0.081312 * f[..., 2], 0, 255)
    u = ((u[:, 0::2] + u[:, 1::2]) / 2).round().astype(np.uint8)
    v = ((v[:, 0::2] + v[:, 1::2]) / 2).round().astype(np.uint8)
    h, w = y.shape
    out = np.empty((h, w * 2), np.uint8)
    if order == 'uyvy':
        out[:, 0::4], out[:, 1::4], out[:, 2::4], out[:, 3::4] = u, y[:, 0::2], v, y[:, 1::2]
    else:
        out[:, 0::4], out[:, 1::4], out[:, 2::4], out[:, 3::4] = y[:, 0::2], u, y[:, 1::2], v
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument('dataset')
    ap.add_argument('out')
    ap.add_argument('--storage', choices=['mcap', 'sqlite3'], required=True)
    ap.add_argument('--encoding', required=True)
    ap.add_argument('--split', choices=['train', 'all'], default='all')
    ap.add_argument('--image-hz', type=float, default=10.0)
    ap.add_argument('--joint-hz', type=float, default=50.0)
    ap.add_argument('--names', default='HeadYaw,HeadPitch')
    ap.add_argument('--image-topic', default='/camera/image_raw')
    ap.add_argument('--hold-ms', type=float, default=30.0,
                    help='the head holds each pose this long before and after its frame')
    ap.add_argument('--cut', action='append', default=[])
    ap.add_argument('--nan-ms', default=None)
    ap.add_argument('--short-positions', type=int, default=None)
    a = ap.parse_args()
    cuts = {int(k): float(f) for k, f in (c.split(':') for c in a.cut)}
    nan = tuple(float(x) * 1e6 for x in a.nan_ms.split(':')) if a.nan_ms else None

    ds = Path(a.dataset)
    index = json.loads((ds / 'dataset.json').read_text())
    frames = [f for f in index['frames'] if a.split == 'all' or f['split'] == 'train']
    yaw_name, pitch_name = a.names.split(',')
    ts = get_typestore(Stores.ROS2_HUMBLE)
    Image = ts.types['sensor_msgs/msg/Image']
    CompressedImage = ts.types['sensor_msgs/msg/CompressedImage']
    JointState = ts.types['sensor_msgs/msg/JointState']
    Header = ts.types['std_msgs/msg/Header']
    Time = ts.types['builtin_interfaces/msg/Time']

    def header(ns, frame_id):
        return Header(stamp=Time(sec=ns // 10**9, nanosec=ns % 10**9), frame_id=frame_id)

    t0 = 1_700_000_000 * 10**9
    image_dt = int(round(1e9 / a.image_hz))
    joint_dt = int(round(1e9 / a.joint_hz))
    hold = int(a.hold_ms * 1e6)
    poses = [(f['head_yaw'], f['head_pitch']) for f in frames]

    def head(t):
        """The head's angles at t ns after t0."""
        i = min(max(t // image_dt, 0), len(poses) - 1)
        dt = t - i * image_dt
        if dt <= hold or i + 1 >= len(poses):
            return poses[i]
        if dt >= image_dt - hold:
            return poses[i + 1]
        s = (dt - hold) / (image_dt - 2 * hold)
        return tuple(p + s * (q - p) for p, q in zip(poses[i], poses[i + 1]))

    compressed = a.encoding in ('jpeg', 'png')
    storage = StoragePlugin.MCAP if a.storage == 'mcap' else StoragePlugin.SQLITE3
    msgs = []  # (t, topic, msg)
    for i, f in enumerate(frames):
        t = i * image_dt
        rgb = np.asarray(PilImage.open(ds / f['file']).convert('RGB'))
        h, w = rgb.shape[:2]
        if compressed:
            buf = io.BytesIO()
            if a.encoding == 'jpeg':
                PilImage.fromarray(rgb).save(buf, format='JPEG', quality=95)
            else:
                PilImage.fromarray(rgb).save(buf, format='PNG')
            data = buf.getvalue()
            if i in cuts:
                data = data[:int(len(data) * cuts[i])]
            m = CompressedImage(header=header(t0 + t, 'camera'), format=a.encoding,
                                data=np.frombuffer(data, np.uint8))
        else:
            if a.encoding == 'mono8':
                data, step = grey(rgb), w
            elif a.encoding == 'bgr8':
                data, step = rgb[..., ::-1], 3 * w
            elif a.encoding in ('yuv422', 'yuyv'):
                data, step = yuv422(rgb, 'uyvy' if a.encoding == 'yuv422' else 'yuyv'), 2 * w
            else:
                data, step = rgb, 3 * w
            m = Image(header=header(t0 + t, 'camera'), height=h, width=w, encoding=a.encoding,
                      is_bigendian=0, step=step, data=np.ascontiguousarray(data).reshape(-1))
        msgs.append((t, a.image_topic, m))
    end = (len(frames) - 1) * image_dt + image_dt // 2
    names = ['LShoulderPitch', pitch_name, 'LShoulderRoll', yaw_name]
    t = 0
    n = 0
    while t <= end:
        y, p = head(t)
        if nan and nan[0] <= t <= nan[1]:
            y = p = float('nan')
        pos = [1.4, p, 0.13, y]
        if n == a.short_positions:
            pos = pos[:-1]
        n += 1
        m = JointState(header=header(t0 + t, ''), name=names,
                       position=np.array(pos, np.float64),
                       velocity=np.zeros(0, np.float64), effort=np.zeros(0, np.float64))
        msgs.append((t, '/joint_states', m))
        t += joint_dt
    msgs.sort(key=lambda x: x[0])

    with Writer(Path(a.out), version=8, storage_plugin=storage) as wr:
        ci = wr.add_connection(a.image_topic, CompressedImage.__msgtype__ if compressed else Image.__msgtype__, typestore=ts)
        cj = wr.add_connection('/joint_states', JointState.__msgtype__, typestore=ts)
        for t, topic, m in msgs:
            c = ci if topic == a.image_topic else cj
            wr.write(c, t0 + t, ts.serialize_cdr(m, c.msgtype))
    print(json.dumps({'images': len(frames), 'joint_states': sum(1 for x in msgs if x[1] == '/joint_states')}))


if __name__ == '__main__':
    main()
