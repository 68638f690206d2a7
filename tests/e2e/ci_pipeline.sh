#!/usr/bin/env bash
# A CI asset pipeline: submit every scene given, wait for each, fail the build if any job does not
# succeed, and download each artifact. Server and token come from NBAKE_URL / NBAKE_TOKEN.
#
#   tests/e2e/ci_pipeline.sh OUT_DIR SCENE [SCENE ...]
#
# Extra `nbake submit` options (e.g. `--set spp=4`) go in NBAKE_SUBMIT_ARGS.
set -euo pipefail

out=$1
shift
mkdir -p "$out"
nbake=${NBAKE:-nbake}
read -r -a extra <<< "${NBAKE_SUBMIT_ARGS:-}"

for scene in "$@"; do
    name=$(basename "$scene")
    name=${name%%.*}
    log="$out/$name.jsonl"
    status=0
    "$nbake" submit "$scene" --kind render --preset quick "${extra[@]}" --wait --json > "$log" || status=$?
    if [ "$status" -ne 0 ]; then
        echo "FAILED: $scene (nbake exit $status)" >&2
        tail -n 1 "$log" >&2 || true
        exit "$status"
    fi
    artifact=$(tail -n 1 "$log" | python3 -c 'import json, sys; print(json.load(sys.stdin)["job"]["artifact_id"])')
    "$nbake" download "$artifact" -o "$out/$name" --json > "$out/$name.files.jsonl"
    echo "ok: $scene -> $out/$name ($artifact)"
done
