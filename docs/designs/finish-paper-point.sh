#!/bin/bash
# After the calibrate grid's last cell (issue 48): commit it, make the final calibrate
# report, move the drafted design into place with the rule's choice filled in, commit it
# (the pre-registration), record its frozen commit, and start its grid from two snapshot
# worktrees: ../pp-grid at the frozen commit (the cells' code) and ../pp-sched at the
# commit recording it (the scheduler, so later changes to this checkout cannot reach a
# running sweep). Run from the repository root of a checkout with .venv and sumo_nets/.
set -euo pipefail
ROOT=$(pwd)
.venv/bin/priqn sweep calibrate --runs-dir results --commit
.venv/bin/priqn report results/calibrate --out docs/results/calibrate
git add docs/results/calibrate
git diff --cached --quiet || git commit -q -m "calibrate report: all 18 cells, the rule's choice is final (priqn report results/calibrate --out docs/results/calibrate)"
git mv docs/designs/paper-point.toml priqn/data/experiments/paper-point.toml
python3 docs/designs/fill_design.py
git add priqn/data/experiments/paper-point.toml
git commit -q -m "paper-point.toml (issue 48): Pr-IQN* vs IQN at the paper's operating point, pre-registered before any of its cells (traffic = calibrate's choice; AdaStop 5/10/15/20 seeds; success primary, violations secondary; 60k decisions)"
D=$(git rev-parse HEAD)
sed -i "s|^code_commits = \[\]  # the frozen commit every cell trains at (the commit that adds this file)|code_commits = [\"$D\"]  # the frozen commit every cell trains at (the commit that adds this file)|; s|^code_commits = \[\]  # the frozen commit\$|code_commits = [\"$D\"]  # the frozen commit|" priqn/data/experiments/paper-point.toml
grep -c "$D" priqn/data/experiments/paper-point.toml
git add priqn/data/experiments/paper-point.toml
git commit -q -m "paper-point.toml: code_commits = ${D:0:12}, the frozen commit its cells train at (../pp-grid)"
A=$(git rev-parse HEAD)
git worktree add -q --detach ../pp-grid "$D"
git worktree add -q --detach ../pp-sched "$A"
cp -r sumo_nets ../pp-grid/ && cp -r sumo_nets ../pp-sched/
cd ../pp-sched
nohup $ROOT/.venv/bin/python -m priqn.cli sweep paper-point --code ../pp-grid --runs-dir $ROOT/results --no-report > ../paper-point.log 2>&1 &
sleep 20; tail -3 ../paper-point.log
