"""python eval_recessed.py RUN OUT.json: RUN's best checkpoint on both engines with the recessed
dense pads of recessed.py (OUT_M, HOLD_HI, SETTLE from the environment), 320 episodes of seed
2024, with the paired (Newcombe) interval of the difference."""
import json
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import recessed  # noqa: E402

recessed.patch()
from daddpg_jax.analysis import engines, evaluation  # noqa: E402

run, out_path = sys.argv[1], sys.argv[2]
n = 320
res = {}
for eng in ("c", "mjx"):
    t0 = time.time()
    pol = evaluation.load_policy(run, best=True, physics=eng)
    s, tr = evaluation.evaluate(pol, episodes=n, seed=2024)
    res[eng] = tr["success"].astype(bool)
    print(eng, "pairs", pol.env.mj_model.npair, float(res[eng].mean()), f"{time.time() - t0:.0f}s", flush=True)
c, mj = res["c"], res["mjx"]
both, c_only, m_only = int((c & mj).sum()), int((c & ~mj).sum()), int((mj & ~c).sum())
out = dict(c=float(c.mean()), mjx=float(mj.mean()), both=both, c_only=c_only, mjx_only=m_only,
           difference=float(c.mean() - mj.mean()),
           ci95=engines.newcombe_paired_interval(both, c_only, m_only, n - both - c_only - m_only))
print(out, flush=True)
json.dump(out, open(out_path, "w"), indent=1, default=float)
