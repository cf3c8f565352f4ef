#!/usr/bin/env python3
"""PyTorch twin of `msr train`'s default conv decoder training, for timing burn against it.

Same work as the burn timing probe (`host/src/train/synthetic.rs`, `timing_probe`): synthetic
faces of 58 x 75 (the same formula), 1040 training and 260 test faces, the default conv decoder
(2-32 dense, 32-(4 x 29 x 38) dense, tanh; ConvTranspose2d 4->1, kernel 4, stride 2, padding 1;
sigmoid; crop to 58 x 75), MSE, Adam (lr 0.005, eps 1e-8, halved every 10 epochs), batch 128,
shuffled, 50 epochs, test loss after every epoch (batches of 512, no gradients).

Run both side by side with `host/bench/train_vs_torch.sh` (needs `pip install torch numpy`); not
part of the test command.
"""
import argparse
import math
import time

import numpy as np
import torch
from torch import nn


def face(h, w, head, noise, rng):
    cx = w / 2.0 + head[0] * w
    cy = h / 2.0 - head[1] * h
    rx, ry = w * 0.3, h * 0.35
    r, c = np.mgrid[0:h, 0:w].astype(np.float32)
    x, y = c + 0.5, r + 0.5
    v = 0.2 + 0.2 * r / h
    d = ((x - cx) / rx) ** 2 + ((y - cy) / ry) ** 2
    v += 0.5 / (1.0 + np.exp(8.0 * (d - 1.0)))
    for ex in (-0.4, 0.4):
        e = ((x - cx - ex * rx) / (0.15 * rx)) ** 2 + ((y - cy + 0.25 * ry) / (0.15 * ry)) ** 2
        v -= 0.45 / (1.0 + np.exp(8.0 * (e - 1.0)))
    v += noise * (rng.random((h, w), dtype=np.float32) - 0.5) * 2.0
    return np.clip(v, 0.0, 1.0).reshape(-1)


@np.errstate(over="ignore")  # exp overflows to inf far from the face: 1 / inf = 0, as in Rust
def samples(n, h, w, seed):
    rng = np.random.default_rng(seed)
    lim = math.radians(5.0)
    heads = rng.uniform(-lim, lim, size=(n, 2)).astype(np.float32)
    faces = np.stack([face(h, w, hd, 0.02, rng) for hd in heads]).astype(np.float32)
    return torch.from_numpy(heads), torch.from_numpy(faces)


class ConvDecoder(nn.Module):
    def __init__(self, h, w, hidden=32, channels=4):
        super().__init__()
        self.h, self.w = h, w
        self.base = (channels, (h + 1) // 2, (w + 1) // 2)
        self.d1 = nn.Linear(2, hidden)
        self.d2 = nn.Linear(hidden, channels * self.base[1] * self.base[2])
        self.up = nn.ConvTranspose2d(channels, 1, kernel_size=4, stride=2, padding=1)
        self.crop = ((2 * self.base[1] - h) // 2, (2 * self.base[2] - w) // 2)

    def forward(self, heads):
        x = torch.tanh(self.d2(torch.tanh(self.d1(heads))))
        y = torch.sigmoid(self.up(x.view(-1, *self.base)))
        t, l = self.crop
        return y[:, 0, t:t + self.h, l:l + self.w].reshape(-1, self.h * self.w)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--epochs", type=int, default=50)
    ap.add_argument("--batch", type=int, default=128)
    ap.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    a = ap.parse_args()
    if a.threads:
        torch.set_num_threads(a.threads)
    torch.manual_seed(0)
    h, w = 58, 75
    tr_h, tr_f = samples(1040, h, w, 1)
    te_h, te_f = samples(260, h, w, 2)
    model = ConvDecoder(h, w)
    opt = torch.optim.Adam(model.parameters(), lr=0.005, eps=1e-8)
    sched = torch.optim.lr_scheduler.StepLR(opt, step_size=10, gamma=0.5)
    gen = torch.Generator().manual_seed(0)
    t0, c0 = time.perf_counter(), time.process_time()
    for epoch in range(a.epochs):
        model.train()
        order = torch.randperm(len(tr_h), generator=gen)
        total = 0.0
        for i in range(0, len(order), a.batch):
            idx = order[i:i + a.batch]
            y = tr_f[idx]
            loss = ((model(tr_h[idx]) - y) ** 2).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
            total += loss.item() * len(idx)
        sched.step()
        model.eval()
        with torch.no_grad():
            sq = sum(((model(te_h[i:i + 512]) - te_f[i:i + 512]) ** 2).sum().item() for i in range(0, len(te_h), 512))
        test = sq / te_f.numel()
    secs, cpu = time.perf_counter() - t0, time.process_time() - c0
    print(f"torch {torch.__version__} ({torch.get_num_threads()} threads): conv: {a.epochs} epochs in {secs:.1f} s ({cpu:.1f} s CPU), "
          f"train {total / len(tr_h):.5f} test {test:.5f}")


if __name__ == "__main__":
    main()
