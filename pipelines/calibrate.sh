#!/usr/bin/env bash
# Learn a camera's calibration (vanishing points VP1/VP2, paper §3) from traffic video and save it as JSON.
#
#   pipelines/calibrate.sh INPUT CALIBRATION.json
#   pipelines/calibrate.sh --check            # only report whether every element is installed
#   pipelines/calibrate.sh --help             # print this text
#
# INPUT        a video file or any URI uridecodebin plays: file:///..., http(s)://..., rtsp://user:pw@cam/stream
# CALIBRATION  where to write the calibration (our calibration JSON, state "vps": vanishing points, no scale yet).
#              Written only once the calibration converged; an earlier file there is replaced only then (written
#              whole, then renamed: a symlink is followed and stays, an earlier file's permissions are kept).
#
# The pipeline (printed before it runs):
#   uridecodebin ! videoconvert ! videoflip ! videoscale ! I420 1:1
#     ! vpdetect mode=learn calibration-file=... ! fakesink
# It stops as soon as vpdetect has saved the calibration (so a live camera is calibrated without Ctrl-C; a file
# is not decoded further than needed). When the input ends first, it exits 1 with vpdetect's reason.
#
# Environment (optional):
#   VPDETECT_OPTS  extra vpdetect properties, e.g. "min-duration=60 max-duration=600 focal-range=500,4000"
# STALL_TIMEOUT (seconds, default 30; 0: wait for ever): a live source that sends no frame this long ends the run
# with an error (GStreamer's watchdog), so a service is restarted instead of hanging on a dead camera.
# ORIENTATION (auto, identity, 90r, 180, 90l, horiz, vert, ul-lr, ur-ll; default auto: as a file's rotation or
# mirroring says, or a stream's tag): the picture turned that way whatever the video says, as trafficcal run
# --orientation turns it — a camera mounted on its side or upside down sends no tag over RTSP (90r: a quarter turn
# clockwise, 90l: counter-clockwise, horiz/vert: mirrored). It is kept in the calibration (field orientation):
# measure.sh, nvr-overlay.sh and trafficcal run given the file turn the picture the same way without being told.
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
# shellcheck source=lib.sh
. "$here/lib.sh"
[[ "${1:-}" == "--help" || "${1:-}" == "-h" ]] && { print_usage "${BASH_SOURCE[0]}"; exit 0; }
# shellcheck source=../scripts/env.sh
. "$here/../scripts/env.sh"

die() { echo "calibrate: error: $*" >&2; exit 2; }

need=(uridecodebin videoconvert videoflip videoscale vpdetect fakesink)


[[ "${1:-}" == "--check" ]] && run_check calibrate "${need[@]}"

[[ $# -eq 2 ]] || die "usage: $(basename "$0") INPUT CALIBRATION.json   (or --check, --help)"
input="$1"
output="$2"

uri="$(input_uri "$input")"
[[ -d "$output" ]] && die "$output: a folder, not a calibration file (e.g. ${output%/}/calibration.json)"
# Written whole beside the file, then renamed over it, as the Python side's fileio.atomic_write does: a symlink is
# followed (the link stays, the file it leads to gets the calibration) and an earlier file's permissions are kept.
target="$output"
if [[ -L "$output" ]]; then
    target="$(readlink -m -- "$output")" || die "$output: a symlink that cannot be followed (a loop?)"
fi
[[ -e "$target" && ! -f "$target" ]] && die "$output: not a regular file: cannot write the calibration there (it" \
    "is written whole, then renamed into place)"
out_dir="$(dirname "$target")"
[[ -d "$out_dir" && -w "$out_dir" ]] || die "$output: directory $out_dir does not exist or is not writable"

require_elements calibrate gstreamer1.0-plugins-base/-good "${need[@]}"  # exit code 2, what to install (lib.sh)

tmp="$(mktemp "$out_dir/.calibrate.XXXXXX")"
log="$(mktemp)"
rm -f "$tmp"  # vpdetect creates it when the calibration converges
cleanup() { rm -f "$tmp" "$log"; }
trap cleanup EXIT

set_stall_watchdog "$uri"  # a live source that stops sending ends the run (lib.sh)
# shellcheck disable=SC2206  # word splitting of the user's property list is intended
set_analysed_video "$uri"  # upright and of square pixels, as the camera model and trafficcal run take them (lib.sh)
set_orientation_prop  # an ORIENTATION is kept in the calibration (its field orientation), for measure.sh and run
pipeline=(uridecodebin "uri=$uri" ! "${stall[@]}" videoconvert ! "${analysed[@]}"
          ! vpdetect mode=learn "calibration-file=$tmp" "${orientation_prop[@]}" ${VPDETECT_OPTS:-} ! fakesink)
echo "calibrate: gst-launch-1.0 -e ${pipeline[*]}" >&2

rc=0
# converged and saved: the stream is ended cleanly (EOS) and vpdetect keeps its file; SIGTERM handled as Ctrl-C
launch --until "$tmp" "${pipeline[@]}" >"$log" 2>&1 || rc=$?

if [[ -s "$tmp" ]]; then
    if [[ -f "$target" ]]; then  # its permission bits (rwx of owner, group, others), not a new file's
        chmod "$(printf '%o' $((0$(stat -c '%a' -- "$target") & 0777)))" "$tmp"
    fi
    mv -f -- "$tmp" "$target"
    echo "calibrate: wrote $output"
    exit 0
fi
reason="$(grep -m 1 -o 'calibration failed: .*' "$log" || true)"  # -m 1, not `| head` (SIGPIPE under pipefail)
if [[ -n "$reason" ]]; then
    echo "calibrate: error: the calibration did not converge: ${reason#calibration failed: }" >&2
else
    grep -v 'should be floating' "$log" | grep -m 5 -E 'ERROR|WARNING|error' >&2 || true
    echo "calibrate: error: no calibration was learnt (gst-launch-1.0 exit code $rc)" >&2
fi
exit 1
