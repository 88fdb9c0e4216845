#!/usr/bin/env bash
# Runs decks with two pmpm binaries and compares what they write, byte for byte: every frame
# (CSV and VTU), run.toml, probes.csv and rigid_bodies.csv (series.csv differs by its wall
# time). For a change that should not change any result (a refactor, a move of code), run it
# with the binary before and the binary after.
#
#   scripts/same_outputs.sh OLD_PMPM NEW_PMPM [DECK ...]      (default: examples/*.toml)
#
# END_TIME=0.05 cuts every deck's simulation.end_time (a quicker check). One thread each, so
# the runs repeat bitwise. Exit status 1 when any deck's outputs differ.
set -euo pipefail
old=$(realpath "$1"); new=$(realpath "$2"); shift 2
decks=("$@")
[ ${#decks[@]} -eq 0 ] && decks=(examples/*.toml)
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
status=0
for deck in "${decks[@]}"; do
  name=$(basename "$deck" .toml)
  copy="$work/$name.toml"
  if [ -n "${END_TIME:-}" ]; then
    sed "s/^end_time *=.*/end_time = $END_TIME/" "$deck" > "$copy"
  else
    cp "$deck" "$copy"
  fi
  # the deck's neighbouring folders (meshes/ its shapes name by relative path) beside the copy
  for folder in "$(dirname "$deck")"/*/; do
    [ -d "$folder" ] || continue
    link="$work/$(basename "$folder")"
    [ -e "$link" ] || ln -s "$(realpath "$folder")" "$link"
  done
  failed=0
  for which in old new; do
    bin=$old; [ $which = new ] && bin=$new
    if ! "$bin" run "$copy" --output "$work/$which-$name" --threads 1 --quiet --force \
        > "$work/$which-$name.log" 2>&1; then
      echo "$name: the $which binary failed: $(tail -1 "$work/$which-$name.log")"
      failed=1
    fi
  done
  if [ $failed = 1 ]; then
    status=1
    continue
  fi
  differs=()
  for f in $(cd "$work/old-$name" && find . -type f ! -name series.csv ! -name checkpoint.bin ! -name .pmpm-lock | sort); do
    cmp -s "$work/old-$name/$f" "$work/new-$name/$f" || differs+=("$f")
  done
  if [ ${#differs[@]} -eq 0 ]; then
    echo "$name: same"
  else
    echo "$name: DIFFERS in ${#differs[@]} file(s), first ${differs[0]}"
    status=1
  fi
done
exit $status
