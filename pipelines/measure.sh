#!/usr/bin/env bash
# Measure every vehicle's speed with the product card's chain and write the per-vehicle results.
#
#   pipelines/measure.sh INPUT OUT_DIR [CALIBRATION]
#   pipelines/measure.sh --check            # only report whether every element is installed
#   pipelines/measure.sh --help             # print this text
#
# INPUT        a video file or any URI uridecodebin plays: file:///..., http(s)://..., rtsp://user:pw@cam/stream
# OUT_DIR      created if needed; receives vehicles.jsonl (one JSON object per vehicle when it leaves),
#              vehicles.csv (the same as CSV), system.json (BrnoCompSpeed results: camera_calibration + cars)
#              and intervals.csv (the traffic count per 15 minutes, lane and direction, rewritten as each
#              interval closes; SPEEDOMETER_OPTS="interval=5" for 5 minutes)
# CALIBRATION  optional calibration JSON (ours, e.g. from calibrate.sh or `trafficcal calibrate-manual`, or any
#              file with a BrnoCompSpeed camera_calibration block): vpdetect uses it instead of learning. Speeds
#              need a scale: from the file, or from bbscale/speedometer; without one, vehicles are written with
#              speed_kmh null and the reason.
#
# The pipeline (printed before it runs) is the product card's line:
#   uridecodebin ! videoconvert ! videoflip ! videoscale ! I420 1:1 ! vpdetect ! vehicledetect
#     ! speedometer events-file=... ! fakesink
# (speedometer runs the tracker itself). Live sources (rtsp://...) run until Ctrl-C or SIGTERM (a service
# stopped); the files are then completed (gst-launch-1.0 -e). Every vehicle is written the moment it leaves,
# so nothing already measured is lost if the run is interrupted. For any input that is not a file,
# speedometer gets start-datetime=now: every vehicle carries the date and time it passed (first_time,
# last_time) by this machine's clock; for a recording, give its start yourself:
# SPEEDOMETER_OPTS="start-datetime=2026-12-05T08:00:00+01:00". For a file, speedometer gets remeasure=true:
# the vehicles that passed before the calibration settled are measured again with the final one at the end, as
# trafficcal run does, so both give the same numbers.
#
# Environment (optional):
#   VPDETECT_OPTS       extra vpdetect properties (e.g. "min-duration=60")
#   VEHICLEDETECT_OPTS  extra vehicledetect properties (e.g. "model=FastestDet.onnx tiles=2x1")
#   SPEEDOMETER_OPTS    extra speedometer properties (e.g. "tau=5 min-track-length=10"; "events-url=https://..."
#                       POSTs each vehicle's event to your system as it leaves)
#   A camera measured again and again (a service restarted, a PTZ preset revisited): give both elements one views
#   folder, VPDETECT_OPTS="views-dir=/var/lib/cam7" SPEEDOMETER_OPTS="views-dir=/var/lib/cam7", and each view's
#   calibration, scale included, is kept there and used at once the next time the camera shows it.
# A live source (rtsp://, udp://, srt://, rtmp://) gets a queue that keeps a second of frames and drops the oldest
# beyond it: a machine too slow for the camera falls behind by at most that much.
# Started again into an OUT_DIR holding an earlier run's vehicles, a live source's run moves them to
# OUT_DIR/earlier-<time of the last vehicle>/ first (a stream cannot be measured again); a file's are replaced.
# STALL_TIMEOUT (seconds, default 30; 0: wait for ever): a live source that sends no frame this long ends the run
# with an error (GStreamer's watchdog), so a service is restarted instead of hanging on a dead camera.
# ORIENTATION (auto, identity, 90r, 180, 90l, horiz, vert, ul-lr, ur-ll; default auto: as a file's rotation or
# mirroring says, or a stream's tag): the picture turned that way whatever the video says, as trafficcal run
# --orientation turns it — a camera mounted on its side or upside down sends no tag over RTSP (90r: a quarter turn
# clockwise, 90l: counter-clockwise, horiz/vert: mirrored). Unset, the one the CALIBRATION keeps (calibrate.sh's
# ORIENTATION, trafficcal calibrate's --orientation: its field orientation) is taken, and said.
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
# shellcheck source=lib.sh
. "$here/lib.sh"
[[ "${1:-}" == "--help" || "${1:-}" == "-h" ]] && { print_usage "${BASH_SOURCE[0]}"; exit 0; }
# shellcheck source=../scripts/env.sh
. "$here/../scripts/env.sh"

die() { echo "measure: error: $*" >&2; exit 2; }

need=(uridecodebin videoconvert videoflip videoscale vpdetect vehicledetect speedometer fakesink)


[[ "${1:-}" == "--check" ]] && run_check measure "${need[@]}"

[[ $# -ge 2 && $# -le 3 ]] || die "usage: $(basename "$0") INPUT OUT_DIR [CALIBRATION]   (or --check, --help)"
input="$1"
out_dir="$2"
calibration="${3:-}"

uri="$(input_uri "$input")"
mkdir -p "$out_dir" 2>/dev/null || die "$out_dir: cannot create the output directory"
[[ -w "$out_dir" ]] || die "$out_dir: output directory is not writable"

require_elements measure gstreamer1.0-plugins-base "${need[@]}"  # exit code 2 and what to install (lib.sh)

vp=(vpdetect)
if [[ -n "$calibration" ]]; then
    [[ -f "$calibration" && -r "$calibration" ]] || die "$calibration: no such calibration file (or not readable)"
    vp=(vpdetect mode=fixed "calibration-file=$calibration")
fi

clock=()
[[ "$uri" == file://* ]] || clock=(start-datetime=now)  # a live source: date the vehicles by this machine's clock
again=()  # a file's vehicles seen before the calibration settled: measured again with the final one, as in run
[[ "$uri" != file://* ]] || again=(remeasure=true)

events="$out_dir/vehicles.jsonl"
kept="$(keep_earlier_live "$uri" "$out_dir")" || die "$out_dir: cannot keep the earlier run's results aside"
[[ -z "$kept" ]] || echo "measure: kept the earlier run's $(grep -c . "$kept/vehicles.jsonl" || true) vehicles of" \
                         "a live stream in $kept (a stream cannot be measured again)" >&2
mapfile -t queue < <(analysis_queue "$uri")  # leaky for a live source (lib.sh)
set_stall_watchdog "$uri"  # a live source that stops sending ends the run (lib.sh)
# shellcheck disable=SC2206  # word splitting of the user's property lists is intended
take_kept_orientation measure "$calibration"  # ORIENTATION unset: the calibration's (lib.sh)
set_analysed_video "$uri"  # upright and of square pixels, as the camera model and trafficcal run take them (lib.sh)
pipeline=(uridecodebin "uri=$uri" ! "${stall[@]}" videoconvert ! "${analysed[@]}" ! "${queue[@]}"
          ! "${vp[@]}" ${VPDETECT_OPTS:-} ! vehicledetect ${VEHICLEDETECT_OPTS:-}
          ! speedometer "events-file=$events" "csv-file=$out_dir/vehicles.csv" "results-file=$out_dir/system.json"
            "intervals-file=$out_dir/intervals.csv" "${clock[@]}" "${again[@]}" ${SPEEDOMETER_OPTS:-} ! fakesink)
echo "measure: gst-launch-1.0 -e ${pipeline[*]}" >&2

rc=0
launch "${pipeline[@]}" || rc=$?  # SIGTERM handled as Ctrl-C (lib.sh)
if [[ "$rc" -ne 0 ]]; then  # no summary as if it had succeeded: one line, and the pipeline's exit code
    so_far=""
    if [[ -s "$events" ]]; then
        so_far="; $events holds $(grep -c . "$events" || true) vehicles"  # measured before it stopped, or by the
        # run before when it stopped before any video (speedometer leaves the files of a run that never started)
    fi
    echo "measure: error: the pipeline failed (gst-launch-1.0 exit code $rc)$so_far" >&2
    exit "$rc"
fi
if [[ -f "$events" ]]; then
    total="$(grep -c . "$events" || true)"
    unmeasured="$(grep -c '"speed_kmh": null' "$events" || true)"
    echo "measure: $total vehicles ($((total - unmeasured)) with a speed) in $events, BrnoCompSpeed results in" \
         "$out_dir/system.json"
    if [[ "$total" -gt 0 && "$unmeasured" -eq "$total" ]]; then
        # the first reason only: grep stops at it (no `| head`, whose early exit would kill grep with SIGPIPE and,
        # under pipefail, the script with 141)
        reason="$(grep -m 1 -o '"reason": "[^"]*"' "$events" || true)"
        reason="${reason#'"reason": "'}"
        echo "measure: note: no vehicle has a speed (first reason: ${reason%'"'}); speeds need a calibration" \
             "with a scale (CALIBRATION argument)" >&2
    fi
fi
exit 0
