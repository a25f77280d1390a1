#!/usr/bin/env bash
# Draw the traffic analysis (road grid, horizon, 3D boxes, ids, speeds, counters) onto a video or a live
# stream and record it as H.264 for an NVR.
#
#   pipelines/nvr-overlay.sh INPUT OUTPUT [CALIBRATION]
#   pipelines/nvr-overlay.sh --check            # only report whether every element is installed
#   pipelines/nvr-overlay.sh --help             # print this text
#
# INPUT        a video file or any URI uridecodebin plays: file:///..., http(s)://..., rtsp://user:pw@cam/stream
# OUTPUT       the recording; its extension (in any case: .MP4 too) picks the container:
#                .mp4  fragmented MP4 (playable while being written and after a crash or power loss)
#                .mkv  Matroska      .ts  MPEG transport stream
#              or a live stream in MPEG-TS for an NVR/VMS or a media server (e.g. to re-serve it as RTSP):
#                udp://HOST:PORT     srt://HOST:PORT (SRT caller; srt://:PORT?mode=listener to listen)
# CALIBRATION  optional calibration JSON (ours, or any file with a BrnoCompSpeed camera_calibration block):
#              vpdetect loads it when it exists, otherwise learns the calibration and saves it there.
#
# The pipeline (printed before it runs):
#   uridecodebin ! videoconvert ! videoflip ! videoscale ! I420 1:1 ! vpdetect ! vehicledetect ! tracker [! speedometer]
#     ! trafficoverlay
#     ! x264enc ! h264parse ! <muxer> ! filesink
# Live sources (rtsp://...) run until Ctrl-C or SIGTERM (a service stopped); the recording is then finalised
# (gst-launch-1.0 -e).
#
# Environment (all optional):
#   ANALYSIS       replaces the analysis chain "vpdetect ! vehicledetect ! tracker ! speedometer" (e.g. to
#                  pass element properties); an empty string draws the overlay of CALIBRATION only
#   OVERLAY_OPTS   extra trafficoverlay properties, e.g. "draw-grid=false grid-spacing=5" or "speed-limit=80"
#                  ("speed-limit=80 class-limits=truck=60,bus=60": trucks and buses held to limits of their own)
#                  (vehicles over the limit drawn in red and counted)
#   ENCODER        encoder element and properties (default "x264enc tune=zerolatency speed-preset=veryfast")
# STALL_TIMEOUT (seconds, default 30; 0: wait for ever): a live source that sends no frame this long ends the run
# with an error (GStreamer's watchdog), so a service is restarted instead of hanging on a dead camera.
# ORIENTATION (auto, identity, 90r, 180, 90l, horiz, vert, ul-lr, ur-ll; default auto: as a file's rotation or
# mirroring says, or a stream's tag): the picture turned that way whatever the video says, as trafficcal run
# --orientation turns it — a camera mounted on its side or upside down sends no tag over RTSP (90r: a quarter turn
# clockwise, 90l: counter-clockwise, horiz/vert: mirrored). Unset, the one an existing CALIBRATION keeps
# (calibrate.sh's ORIENTATION, trafficcal calibrate's --orientation: its field orientation) is taken, and said;
# a calibration vpdetect learns here keeps the ORIENTATION given.
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
# shellcheck source=lib.sh
. "$here/lib.sh"
[[ "${1:-}" == "--help" || "${1:-}" == "-h" ]] && { print_usage "${BASH_SOURCE[0]}"; exit 0; }
# shellcheck source=../scripts/env.sh
. "$here/../scripts/env.sh"

die() { echo "nvr-overlay: error: $*" >&2; exit 2; }

encoder="${ENCODER:-x264enc tune=zerolatency speed-preset=veryfast}"
encoder_element="${encoder%% *}"
default_analysis=1
if [[ -n "${ANALYSIS+set}" ]]; then
    default_analysis=0
    analysis="$ANALYSIS"
fi

need=(uridecodebin videoconvert videoflip videoscale trafficoverlay h264parse "$encoder_element")
if [[ $default_analysis == 1 ]]; then
    need+=(vpdetect vehicledetect tracker)
fi


[[ "${1:-}" == "--check" ]] && run_check nvr-overlay "${need[@]}" speedometer mp4mux matroskamux mpegtsmux

[[ $# -ge 2 && $# -le 3 ]] || die "usage: $(basename "$0") INPUT OUTPUT [CALIBRATION]   (or --check, --help)"
input="$1"
output="$2"
calibration="${3:-}"

uri="$(input_uri "$input")"

output="$(lower_scheme "$output")"  # a URI's scheme in any case (RFC 3986: UDP:// is udp://), as GStreamer reads it
sink=(filesink "location=$output")
case "$output" in
    udp://*)
        hostport="${output#udp://}"
        host="${hostport%:*}"; port="${hostport##*:}"
        [[ -n "$host" && "$port" =~ ^[0-9]+$ && "$hostport" == *:* ]] || die "$output: expected udp://HOST:PORT"
        muxer="mpegtsmux alignment=7" ; mux_element=mpegtsmux ; sink=(udpsink "host=$host" "port=$port")
        need+=(udpsink) ;;
    srt://*)
        muxer="mpegtsmux alignment=7" ; mux_element=mpegtsmux ; sink=(srtsink "uri=$output")
        need+=(srtsink) ;;
    *://*) die "$output: unsupported output URI (use udp://HOST:PORT or srt://HOST:PORT, or a file)" ;;
    *.[mM][pP]4) muxer="mp4mux fragment-duration=1000" ; mux_element=mp4mux ;;
    *.[mM][kK][vV]) muxer="matroskamux" ; mux_element=matroskamux ;;
    *.[tT][sS]) muxer="mpegtsmux" ; mux_element=mpegtsmux ;;
    *) die "$output: unknown container (use .mp4, .mkv or .ts, or udp:// / srt://)" ;;
esac
need+=("$mux_element")
if [[ "$output" != *://* ]]; then
    out_dir="$(dirname "$output")"
    [[ -d "$output" ]] && die "$output: a folder, not a recording file"
    [[ -d "$out_dir" && -w "$out_dir" ]] || die "$output: directory $out_dir does not exist or is not writable"
fi

require_elements nvr-overlay gstreamer1.0-plugins-good/-bad/-ugly "${need[@]}"  # exit code 2, what to install

cal_prop=()
if [[ -n "$calibration" ]]; then
    if [[ -e "$calibration" ]]; then
        [[ -r "$calibration" ]] || die "$calibration: cannot read the calibration file"
    fi
    cal_prop=("calibration-file=$calibration")
    [[ ! -e "$calibration" ]] || take_kept_orientation nvr-overlay "$calibration"  # ORIENTATION unset (lib.sh)
fi
set_orientation_prop  # vpdetect keeps it in a calibration it learns (lib.sh)

if [[ $default_analysis == 1 ]]; then
    # an array, not a string split again: a calibration path with a space stays one property
    chain=(vpdetect "${cal_prop[@]}" "${orientation_prop[@]}" ! vehicledetect ! tracker)
    if gst-inspect-1.0 --exists speedometer 2>/dev/null; then
        chain+=(! speedometer)
    else
        echo "nvr-overlay: note: element 'speedometer' is not installed: vehicles are drawn without speeds" >&2
    fi
    overlay_cal=()
else
    # shellcheck disable=SC2206  # word splitting of the user's ANALYSIS is intended
    chain=($analysis)
    overlay_cal=("${cal_prop[@]}")  # no vpdetect: the overlay draws the given calibration itself
fi

mapfile -t queue < <(analysis_queue "$uri")  # leaky for a live source (lib.sh)
set_stall_watchdog "$uri"  # a live source that stops sending ends the run (lib.sh)
# shellcheck disable=SC2206  # word splitting of the user's property lists is intended
set_analysed_video "$uri"  # upright and of square pixels, as the camera model and trafficcal run take them (lib.sh)
pipeline=(uridecodebin "uri=$uri" ! "${stall[@]}" videoconvert ! "${analysed[@]}" ! "${queue[@]}")
if [[ ${#chain[@]} -gt 0 ]]; then
    pipeline+=(! "${chain[@]}")
fi
# shellcheck disable=SC2206
set_even_i420  # an even size for the H.264 encoder (x264 refuses an odd one, 1281x721: scaled by a pixel)
pipeline+=(! trafficoverlay "${overlay_cal[@]}" ${OVERLAY_OPTS:-} ! videoconvert ! videoscale
           ! "$even_i420" ! $encoder ! h264parse ! $muxer
           ! "${sink[@]}")

echo "nvr-overlay: gst-launch-1.0 -e ${pipeline[*]}" >&2
rc=0
# SIGTERM handled as Ctrl-C: the recording is completed, and the script waits for it (lib.sh). Not bare: under
# set -e a failing gst-launch-1.0 must still reach the line below.
launch "${pipeline[@]}" || rc=$?
if [[ "$rc" -ne 0 ]]; then
    so_far=""
    if [[ "$output" != *://* && -s "$output" ]]; then so_far="; what was recorded before it is in $output"; fi
    echo "nvr-overlay: error: the pipeline failed (gst-launch-1.0 exit code $rc)$so_far" >&2
    exit "$rc"
fi
