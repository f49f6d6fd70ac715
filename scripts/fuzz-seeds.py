#!/usr/bin/env python3
"""Writes the seed corpus of tests/fuzz_build.c into tests/fuzz/ (small hand-designed inputs).

Usage: scripts/fuzz-seeds.py [dir]     (default tests/fuzz; existing seed-* files are replaced,
                                         other files - e.g. crash reproducers - are kept)

Input layout (see fz_parse_options in tests/fuzz_build.c):
  0 builder A (0..4 = top-down .. ploc-parallel)   1 builder B
  2 flags: 1 skip_invalid, 2 indexed, 4|8 coordinate mode, 0x80 fail an allocation
  3 max_leaf_size  4 radius (>= 240: 256 + (r-240) % 3)  5 threads-1  6 stride index
    (0:0 1:12 2:16 3:20 4:12 5:0 6:8 7:4)  7 allocation to fail  8 vertex count
  9 triangle count (indexed)  10 rays from bytes (% 16)
  11 extra: 1 costs, 2 split budget, 4 16-bit max_leaf, 8 soup declares one triangle more,
            16 batch calls, 32 rebuild from boxes, 64 tmin = -inf on the fixed rays
  then: max_leaf (u16), costs (3 floats), split budget (float) when flagged; vertices; indices
  (1 byte each, 255 = out of range); rays (origin, dir, mode byte, [tmin], [tmax]).
Coordinate modes: 0 raw float32, 1 int8/4, 2 int16/256, 3 int8/4 with bytes >= 248 escaping to
a raw float32.
"""
import math
import os
import struct
import sys

TD, BU, SAH, PLOC, PAR = range(5)


def coord(mode, x):
    if mode == 0:
        return struct.pack('<f', x)
    if mode == 1:
        return struct.pack('<b', int(round(x * 4)))
    if mode == 2:
        return struct.pack('<h', int(round(x * 256)))
    if isinstance(x, float) and (math.isnan(x) or math.isinf(x) or abs(x) > 30 or x * 4 != int(x * 4)):
        return bytes([248]) + struct.pack('<f', x)
    return bytes([int(round(x * 4)) + 124])


def seed(a=PLOC, b=PAR, skip=0, indexed=0, mode=1, fail=None, leaf=0, radius=0, threads=2, stride=0,
         verts=(), tris=(), rays=(), costs=None, split=None, leaf16=None, declare_more=0, batch=0,
         boxes=0, negative_tmin=0):
    flags = skip | (2 if indexed else 0) | (mode << 2) | (0x80 if fail is not None else 0)
    extra = ((1 if costs else 0) | (2 if split is not None else 0) | (4 if leaf16 is not None else 0) |
             (8 if declare_more else 0) | (16 if batch else 0) | (32 if boxes else 0) |
             (64 if negative_tmin else 0))
    out = bytes([a, b, flags, leaf, radius, threads - 1, stride, fail or 0, len(verts), len(tris),
                 len(rays), extra])
    if leaf16 is not None:
        out += struct.pack('<H', leaf16)
    if costs:
        out += struct.pack('<3f', *costs)
    if split is not None:
        out += struct.pack('<f', split)
    for v in verts:
        out += b''.join(coord(mode, c) for c in v)
    for t in tris:
        out += bytes(t)
    for o, d, tmin, tmax in rays:
        out += b''.join(coord(mode, c) for c in o + d)
        m = (1 if tmin is not None else 0) | (2 if tmax is not None else 0)
        out += bytes([m])
        if tmin is not None:
            out += coord(mode, tmin)
        if tmax is not None:
            out += coord(mode, tmax)
    return out


def soup(*tris):
    return [v for t in tris for v in t]


T0 = ((0, 0, 0), (1, 0, 0), (0, 1, 0))
UP = ((0.25, 0.25, -2), (0, 0, 1), None, None)


def grid(n, z=0.0, h=0.5):
    verts = [(i * h, j * h, z) for j in range(n + 1) for i in range(n + 1)]
    tris = []
    for j in range(n):
        for i in range(n):
            v = j * (n + 1) + i
            tris += [(v, v + 1, v + n + 2), (v, v + n + 2, v + n + 1)]
    return verts, tris


def seeds():
    s = {}
    s['empty'] = b''
    s['header-only'] = seed(verts=())
    s['one'] = seed(verts=soup(T0), rays=[UP])
    s['two-identical'] = seed(a=TD, b=BU, verts=soup(T0, T0), rays=[UP, ((0.25, 0.25, 2), (0, 0, -1), None, None)])
    s['copies'] = seed(a=BU, b=PAR, verts=soup(*[((0.5, 0.25, 1), (1.5, 0.5, 1), (0.75, 1.25, 1.75))] * 80),
                       threads=3)
    s['degenerate'] = seed(a=SAH, b=PLOC, verts=soup(((1, 1, 1),) * 3, ((0, 0, 0), (1, 2, 3), (2, 4, 6)),
                                                     ((2, 3, 4), (3, 1, 2), (4, -1, 0)),
                                                     ((1, 0, 0), (1, 0, 0), (2, 0, 0)), T0))
    bad = soup(T0, ((float('nan'), 0, 0), (1, 1, 1), (0, 1, 1)), ((2, 2, 2), (3, float('inf'), 2), (2, 3, 2)), T0)
    s['nan-refused'] = seed(mode=3, verts=bad)
    s['nan-skipped'] = seed(mode=3, skip=1, verts=bad, rays=[UP])
    s['inf-skipped-td'] = seed(a=TD, b=SAH, mode=3, skip=1, verts=soup(((float('-inf'), 0, 0), (1, 0, 0), (0, 1, 0)), T0))
    gv, gt = grid(5)
    s['grid-indexed'] = seed(a=PLOC, b=TD, indexed=1, verts=gv, tris=gt, rays=[((1.0, 1.0, 3), (0, 0, -1), None, None)])
    gv2, gt2 = grid(3)
    gt2[4] = (0, 255, 1)
    s['index-out-of-range'] = seed(indexed=1, verts=gv2, tris=gt2)
    s['soup-too-few-vertices'] = seed(verts=soup(T0, T0), declare_more=1)
    s['stride-8'] = seed(stride=6, verts=soup(T0))
    s['stride-16'] = seed(a=BU, stride=2, verts=soup(T0, ((0, 0, 1), (1, 0, 1), (0, 1, 1))), rays=[UP])
    s['stride-20-indexed'] = seed(a=PAR, b=SAH, stride=3, indexed=1, verts=gv2, tris=grid(3)[1])
    s['leaf-255'] = seed(a=TD, b=PLOC, leaf=255, verts=gv, indexed=1, tris=gt)
    s['leaf-1'] = seed(a=PLOC, b=BU, leaf=1, verts=gv, indexed=1, tris=gt)
    s['leaf-256'] = seed(leaf16=256, verts=soup(T0))
    s['radius-256'] = seed(radius=240, verts=gv, indexed=1, tris=gt)
    s['radius-257'] = seed(radius=241, verts=soup(T0))
    s['radius-1'] = seed(a=PAR, b=PLOC, radius=1, threads=3, verts=gv, indexed=1, tris=gt)
    s['costs-negative'] = seed(mode=0, costs=(1.0, -1.0, 1.0), verts=soup(T0))
    s['costs-nan'] = seed(mode=0, costs=(float('nan'), 0.0, 1.0), verts=soup(T0))
    s['costs-valid'] = seed(a=PLOC, b=SAH, costs=(2.0, 0.5, 1.0), verts=gv, indexed=1, tris=gt)
    s['split-nan'] = seed(a=SAH, split=float('nan'), verts=soup(T0))
    s['split-2'] = seed(a=SAH, split=2.0, verts=soup(T0))
    s['split-1'] = seed(a=SAH, b=TD, split=1.0, verts=gv, indexed=1, tris=gt)
    for k in (0, 3, 9, 17):
        s['fail-alloc-%d' % k] = seed(a=[TD, BU, PLOC, PAR][k % 4], fail=k, skip=1, mode=3,
                                      verts=soup(T0, ((float('nan'), 0, 0), (1, 1, 1), (0, 1, 1)), *[T0] * 10))
    s['huge-coordinates'] = seed(a=BU, b=PLOC, mode=0, verts=soup(((-3e38, 0, 0), (-3e38, 1, 0), (-3e38, 0, 1)),
                                                                   ((3e38, 0, 0), (3e38, 1, 0), (3e38, 0, 1))))
    s['far-1e6'] = seed(mode=0, verts=soup(*[((1e6 + i, 1e6, 1e6), (1e6 + i + 0.5, 1e6, 1e6 + 0.5),
                                              (1e6 + i, 1e6 + 0.5, 1e6)) for i in range(12)]))
    s['denormal-direction'] = seed(a=TD, mode=0, verts=soup(((5e-31, -1, 1e9), (1, -1, 1e9), (5e-31, 1, 1e9))),
                                   rays=[((0.0, 0.0, 0.0), (1e-39, 0.0, 1.0), None, None)])
    s['negative-tmin'] = seed(a=TD, b=PLOC, verts=soup(T0), negative_tmin=1,
                              rays=[((0.25, 0.25, 1), (0, 0, 1), -30.0, None)])
    chain, x, w = [], 0.0, 0.01
    for i in range(40):
        chain.append(((x, 0.0, 0.0), (x + w, 0.0, w * 0.5), (x + 0.5 * w, w, 0.0)))
        x, w = x + w, w * 1.5
    s['chain'] = seed(a=PLOC, b=PAR, mode=0, verts=soup(*chain))
    s['nested'] = seed(a=PAR, b=PLOC, mode=2, radius=2,
                       verts=soup(*[((-r, -r, 0), (r, -r, 0), (0, r, 0)) for r in (1 + 0.5 * i for i in range(60))]))
    s['plane-axis-rays'] = seed(a=SAH, b=BU, batch=1, boxes=1, verts=gv, indexed=1, tris=gt,
                                rays=[((1.0, 0.5, 0.0), (1, 0, 0), None, None), ((0.5, 0.5, 0.0), (0, -1, 0), None, 2.0)])
    s['boxes-batch'] = seed(a=PLOC, b=TD, batch=1, boxes=1, skip=1, mode=3,
                            verts=soup(T0, ((0, 0, float('nan')), (1, 1, 1), (0, 1, 1)), ((1, 1, 1), (2, 1, 1), (1, 2, 1))))
    return s


def main():
    out = sys.argv[1] if len(sys.argv) > 1 else os.path.join(os.path.dirname(__file__), '..', 'tests', 'fuzz')
    os.makedirs(out, exist_ok=True)
    for f in os.listdir(out):
        if f.startswith('seed-'):
            os.remove(os.path.join(out, f))
    for name, data in seeds().items():
        assert len(data) <= 4096, name
        with open(os.path.join(out, 'seed-' + name), 'wb') as f:
            f.write(data)
    print('%d seeds in %s' % (len(seeds()), out))


if __name__ == '__main__':
    main()
