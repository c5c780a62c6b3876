"""Fill paper-point.toml's placeholders from the final calibrate report (issue 48).

Run from the repository root by docs/designs/finish-paper-point.sh, after the design has
been moved to priqn/data/experiments/. Refuses while the calibrate report is provisional.
"""

import glob
import json
import statistics
import sys
from pathlib import Path

meta = json.loads(Path("docs/results/calibrate/meta.json").read_text())
if not meta.get("final"):
    sys.exit(f"calibrate report not final: missing {meta.get('missing')}")
chosen = meta["chosen"]
l1 = meta["distances"][chosen]
cal = Path("priqn/data/experiments/calibrate.toml").read_text()
block = cal[cal.index(f'name = "{chosen}"') :]
traffic = block[block.index('traffic = "') + 11 :].split('"')[0]
walls = []
for d in glob.glob(f"results/calibrate/{chosen}__seed*"):
    m = json.loads(Path(d, "meta.json").read_text())
    if m.get("steps_done") == 60000 and len(m.get("sessions") or [1]) <= 1:
        walls.append(m["wall_s"] / 60)
minutes = statistics.mean(walls)
hours = 40 * minutes / 2 / 60
p = Path("priqn/data/experiments/paper-point.toml")
s = p.read_text()
s = s[s.index("# The headline question") :]  # the draft's own header goes
s = s.replace("TRAFFIC_CHOSEN_BY_CALIBRATE", traffic)
s = s.replace("L1_OF_CHOSEN", f"{l1:.3f}")
s = s.replace(
    "CELL_MINUTES",
    f"{minutes:.0f} min on average\n#              ({len(walls)} uninterrupted cells, two at a time beside other work)",
)
s = s.replace("WORST_CASE_HOURS", f"{hours:.0f} h of training")
assert "CHOSEN" not in s and "_HOURS" not in s and "_MINUTES" not in s
p.write_text(s)
print(chosen, traffic, l1, round(minutes, 1), round(hours, 1))
