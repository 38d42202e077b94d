"""Adaptive sampling against uniform sampling on the bundled scenes (issue 22).

For each of the Cornell box, glass and Veach MIS at 128 px wide: an adaptive render
(--adaptive --noise E, at most 1024 spp, tiles of 16, batches of 8), a uniform render
with the same average spp, one with the spp that takes the adaptive render's time,
and a reference at 16x the uniform spp; prints relMSE against the reference and the
ratios (uniform / adaptive: above 1 means adaptive is better). Reads EXRs with
Mitsuba 3's Bitmap (pip install mitsuba). Usage: python3 bench/adaptive_compare.py [E]
"""
import os, subprocess, sys, tempfile, time
import numpy as np
import mitsuba as mi
mi.set_variant('scalar_rgb')
ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), '..')
BIN = os.path.join(ROOT, 'target/release/coordinator')
W = 128
def render(scene, out, args):
    t = time.perf_counter()
    subprocess.run([BIN, 'render', os.path.join(ROOT, 'scenes', scene, 'scene.toml'), '-q', '--width', str(W),
                    '--tile', '16', '--batch-spp', '8', '--local-workers', '0', '-o', out] + args, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t
def read(path):
    b = mi.Bitmap(path)
    root = dict(b.split())['<root>']
    names = [root.struct_()[i].name for i in range(root.channel_count())]
    a = np.array(root)
    ch = lambda n: a[..., names.index(n)]
    return np.stack([ch('R'), ch('G'), ch('B')], -1), ch('samples')
def relmse(x, r):
    return float(np.mean((x - r) ** 2 / (r * r + 0.01)))
noise = sys.argv[1] if len(sys.argv) > 1 else '0.05'
for scene in ['cornell-box', 'glass', 'veach-mis']:
    d = os.path.join(tempfile.gettempdir(), f'tilefarm-adaptive-{scene}')
    ta = render(scene, d + '-a.exr', ['--spp', '1024', '--adaptive', '--noise', noise])
    a, counts = read(d + '-a.exr')
    s = float(counts.mean())
    su = max(1, int(round(s)))
    tu = render(scene, d + '-u.exr', ['--spp', str(su)])
    u, _ = read(d + '-u.exr')
    st = max(1, int(round(su * ta / tu)))
    tt = render(scene, d + '-t.exr', ['--spp', str(st)])
    t_, _ = read(d + '-t.exr')
    tr = render(scene, d + '-r.exr', ['--spp', str(16 * su)])
    r, _ = read(d + '-r.exr')
    ea, eu, et = relmse(a, r), relmse(u, r), relmse(t_, r)
    print(f'{scene:12s} noise {noise}: adaptive avg {s:.1f} spp (min {counts.min():.0f}, max {counts.max():.0f}) {ta:.2f}s relMSE {ea:.5f} | '
          f'uniform {su} spp {tu:.2f}s relMSE {eu:.5f} (ratio {eu/ea:.2f}) | equal time {st} spp {tt:.2f}s relMSE {et:.5f} (ratio {et/ea:.2f}) | ref {16*su} spp')
