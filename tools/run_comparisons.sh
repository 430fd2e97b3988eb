#!/usr/bin/env bash
# The comparison matrix of README.md: mirror sphere vs the analytic reference, then Mitsuba vs
# ours on the mirror sphere, the procedural can, thermos cap and rough sphere under courtyard
# and studio. One JSON line per case on stdout (and in $OUT/results.jsonl).
#
#   bash tools/run_comparisons.sh [OUT_DIR] [ALP_BIN]
#
# ALP_BIN defaults to target/release/alp (build it with `cargo build --release -p alp`).
# ROUGH_SPP (default 4096) and MIRROR_SPP (default 1024) set the sample counts.
set -euo pipefail
HERE="$(cd "$(dirname "$0")" && pwd)"
ROOT="$(dirname "$HERE")"
OUT="${1:-/tmp/alp_mitsuba}"
ALP="${2:-$ROOT/target/release/alp}"
ROUGH_SPP="${ROUGH_SPP:-4096}"
MIRROR_SPP="${MIRROR_SPP:-1024}"
ENVS="${ENVS:-courtyard studio}"
mkdir -p "$OUT"
RES="$OUT/results.jsonl"
: > "$RES"
run() { python3 "$HERE/mitsuba_compare.py" "$@" | tee -a "$RES"; }

python3 "$HERE/make_test_scenes.py" --out-dir "$OUT/scenes" > /dev/null
for k in can cap sphere; do
  [ -f "$OUT/probes/$k/probe.json" ] || "$ALP" probe make "$k" --out "$OUT/probes/$k"
done

for env in $ENVS; do
  E="$ROOT/assets/envmaps/$env.exr"
  # 1. Mitsuba's mirror sphere vs the analytic numpy reference, and ours vs Mitsuba
  M="$OUT/mirror_$env"
  python3 "$HERE/mirror_sphere_reference.py" --env "$E" --out-dir "$M" --sub 16 > /dev/null
  run --probe "$M/probe" --pose "$M/pose.json" --camera "$M/camera.json" --env "$E" \
      --spp "$MIRROR_SPP" --ours "$M/analytic.exr" --mask "$M/analytic_mask.png" \
      --out-dir "$M/mitsuba_vs_analytic" --label "mirror-sphere/$env: analytic vs mitsuba"
  run --probe "$M/probe" --pose "$M/pose.json" --camera "$M/camera.json" --env "$E" \
      --spp "$MIRROR_SPP" --alp-bin "$ALP" --ours-noise \
      --out-dir "$M/ours_vs_mitsuba" --label "mirror-sphere/$env: ours vs mitsuba"
  # 2. procedural probes: ours vs Mitsuba with our Schlick Fresnel (the model exactly), then the
  #    same image of ours vs Mitsuba's `material: none` Fresnel (the known model difference)
  for k in can cap sphere; do
    D="$OUT/${k}_$env"
    run --probe "$OUT/probes/$k" --pose "$OUT/scenes/pose_$k.json" --camera "$OUT/scenes/camera.json" \
        --env "$E" --spp "$ROUGH_SPP" --alp-bin "$ALP" --ours-noise --out-dir "$D/schlick" \
        --label "$k/$env: ours vs mitsuba (schlick, direct)"
    run --probe "$OUT/probes/$k" --pose "$OUT/scenes/pose_$k.json" --camera "$OUT/scenes/camera.json" \
        --env "$E" --spp "$ROUGH_SPP" --ours "$D/schlick/ours.exr" --mask "$D/schlick/ours_mask.png" \
        --fresnel none --out-dir "$D/fresnel_none" \
        --label "$k/$env: ours vs mitsuba (material none, direct)"
  done
  # 3. the cap with Mitsuba's own path integrator (occlusion tested, visibility folded)
  D="$OUT/cap_$env"
  run --probe "$OUT/probes/cap" --pose "$OUT/scenes/pose_cap.json" --camera "$OUT/scenes/camera.json" \
      --env "$E" --spp "$ROUGH_SPP" --ours "$D/schlick/ours.exr" --mask "$D/schlick/ours_mask.png" \
      --integrator path --fresnel none --out-dir "$D/path" \
      --label "cap/$env: ours vs mitsuba path (occluded, material none)"
done
