"""Monte Carlo estimate of the space a particle scans for neighbours (in H^3, H the support radius)
with cells of H / k, k = 1, 2, 3, cells farther than H skipped, and the rows of cells it sets up
(docs/BENCHMARKS.md, "Grid cells of H / 2"). The support sphere is 4.19 H^3.

    python3 scripts/investigations/cell_volume_estimate.py
"""
import numpy as np, itertools
rng=np.random.default_rng(0)
def vol(k, N=20000):
    s=1.0/k  # cell size, H=1
    tot=0.0; rows=0
    for _ in range(N):
        p=rng.random(3)*s
        r=int(np.ceil(k))  # cells each side
        v=0
        for dz in range(-k,k+1):
            gz = max(0, (dz*s - p[2]) if dz>0 else (p[2] - (dz+1)*s)) if dz!=0 else 0
            for dy in range(-k,k+1):
                gy = max(0, (dy*s - p[1]) if dy>0 else (p[1] - (dy+1)*s)) if dy!=0 else 0
                if gz*gz+gy*gy>=1: continue
                cnt=0
                for dx in range(-k,k+1):
                    gx = max(0, (dx*s - p[0]) if dx>0 else (p[0] - (dx+1)*s)) if dx!=0 else 0
                    if gz*gz+gy*gy+gx*gx<1: cnt+=1
                v+=cnt; rows+=1
        tot+=v*s**3
    return tot/N, rows/N
for k in (1,2,3):
    print(k, vol(k,3000))
print("sphere", 4/3*np.pi)
