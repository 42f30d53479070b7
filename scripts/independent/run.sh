#!/usr/bin/env bash
# Make (if missing), calibrate and score independent recordings; prints the table of docs/validation.md.
#   scripts/independent/run.sh                 # the twenty-two recordings of docs/validation.md
#   scripts/independent/run.sh 11 h101         # some of them (a tag: the seed, or h + the seed at --harsh 1/2)
#   scripts/independent/run.sh ud101 hpark102  # scenario recordings (scenarios.txt: tag, seed, switches)
# Files go to $BASE (default out/independent). Run from the repository's root after scripts/setup.sh.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
root="$(cd "$here/../.." && pwd)"
py="$root/.venv/bin/python"
base="${BASE:-out/independent}"
mkdir -p "$base"
export BASE="$base"
tags=("$@")
[ ${#tags[@]} -eq 0 ] && tags=(11 22 33 44 h101 h102 h103 h201 h202 h203 66 h104 h204 67 h105 h205 68 h106 h206 69 h107 h207)
for tag in "${tags[@]}"; do
  rec="$base/rec_$tag.mcap"
  scenario="$(awk -v t="$tag" '$1 == t {$1 = ""; print; exit}' "$here/scenarios.txt")"
  if [ ! -f "$rec" ]; then
    if [ -n "$scenario" ]; then  # a scenario tag: its seed and switches from scenarios.txt
      # shellcheck disable=SC2086
      "$py" "$here/gen.py" $scenario --out "$rec" > "$base/gen_$tag.log" 2>&1
    elif [[ "$tag" == h* ]]; then
      seed="${tag#h}"; level="${seed:0:1}"
      "$py" "$here/gen.py" "$seed" --harsh "$level" --out "$rec" > "$base/gen_$tag.log" 2>&1
    else
      "$py" "$here/gen.py" "$tag" --out "$rec" > "$base/gen_$tag.log" 2>&1
    fi
  fi
  set +e
  "$root/.venv/bin/plsgraph" calibrate "$rec" --board acircles_4x11_a2 --out "$base/out_$tag" --force \
    > "$base/cal_$tag.log" 2>&1
  echo "exit=$?" >> "$base/cal_$tag.log"
  set -e
done
"$py" "$here/table.py" "${tags[@]}"
