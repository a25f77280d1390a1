# Shared by the pipeline scripts (sourced, not run): element checks, input URIs and pipeline pieces.
# The sourcing script defines die() (its own error prefix) before calling input_uri or the set_* functions.

# The decoded video as the elements take it, upright and of square pixels, and an H.264 encoder's input of an even
# size: pipeline pieces trafficcal run uses too, written once in gst_trafficcal/gst/chains.py (env.sh makes it
# importable). Both set arrays of words for the scripts' pipelines; they exit through die() when Python fails.
set_analysed_video() {  # INPUT: sets `analysed` to (videoflip video-direction=... ! videoscale ! I420,PAR 1/1)
    # A phone's or a body camera's rotated recording is turned as its file says (read before the pipeline starts,
    # as trafficcal run reads it: with video-direction=auto vpdetect first saw the stored size and refused a
    # calibration of the upright picture); a DVR's D1 or a 480x360 stored for a 640x360 picture gets square pixels.
    # ORIENTATION (auto, identity, 90r, 180, 90l, horiz, vert, ul-lr, ur-ll; as trafficcal run --orientation):
    # turns the picture that way whatever the video says (a camera mounted on its side: RTP carries no tag).
    ask_chains analysed "$1" "${ORIENTATION:-auto}"
    mapfile -t analysed <<<"$chains_answer"
}

ask_chains() {  # ARGS...: sets `chains_answer` to what `python -m gst_trafficcal.gst.chains ARGS` prints
    # Its own refusal (exit code 3: a bad ORIENTATION, a calibration file it cannot read) goes through die() as
    # it says it; any other failure (no project set up: Python cannot import it) with what to do.
    local rc=0
    chains_answer="$(python -m gst_trafficcal.gst.chains "$@")" || rc=$?
    [[ $rc == 3 ]] && die "$chains_answer"
    [[ $rc == 0 ]] || die "cannot set up the pipeline (is the project set up: scripts/setup.sh?)"
}

take_kept_orientation() {  # NAME CALIBRATION: with ORIENTATION unset, the one the calibration file keeps (saying so)
    # As trafficcal run --calibration takes it: calibrate.sh (vpdetect orientation=...) and trafficcal calibrate keep
    # the ORIENTATION / --orientation the picture was turned by in the file's field orientation. A bad field: die.
    local kept
    [[ -z "${ORIENTATION:-}" && -n "$2" ]] || return 0
    ask_chains kept-orientation "$2"
    kept="$chains_answer"
    [[ -n "$kept" ]] || return 0
    ORIENTATION="$kept"
    echo "$1: orientation kept in $2: $kept (ORIENTATION=auto: as the video says)" >&2
}

set_orientation_prop() {  # sets `orientation_prop` to vpdetect's orientation=... (none for auto): kept in the file
    orientation_prop=()
    case "${ORIENTATION:-auto}" in
        auto|AUTO|"") ;;
        *) orientation_prop=("orientation=$ORIENTATION") ;;
    esac
}

set_even_i420() {  # sets `even_i420` to the caps of I420 of an even size (x264 refuses an odd one, 1281x721)
    ask_chains even-i420
    even_i420="$chains_answer"
}

check_elements() {  # prints the missing elements, one per line
    local e
    for e in "$@"; do
        gst-inspect-1.0 --exists "$e" 2>/dev/null || echo "$e"
    done
}

require_elements() {  # NAME HINT ELEMENT...: returns when every ELEMENT is installed, else says which are not
    # (one line each on stderr: a gst-trafficcal element points to the project's set-up, any other to GStreamer's
    # plugins, HINT naming their packages) and exits with code 2
    local name="$1" hint="$2" missing e
    shift 2
    missing="$(check_elements "$@")"
    [[ -n "$missing" ]] || return 0
    for e in $missing; do
        case "$e" in
            vpdetect|vehicledetect|tracker|speedometer|trafficoverlay|bbscale)
                echo "$name: error: GStreamer element '$e' is not installed (gst-trafficcal element; is the" \
                     "project set up: scripts/setup.sh, and does 'gst-inspect-1.0 $e' work after" \
                     "'. scripts/env.sh'?)" >&2 ;;
            *)
                echo "$name: error: GStreamer element '$e' is not installed (install the GStreamer plugin" \
                     "that provides it, e.g. $hint)" >&2 ;;
        esac
    done
    exit 2
}

run_check() {  # NAME ELEMENT...: the scripts' --check mode; exits 0 when every element is installed, else 1
    local name="$1" missing
    shift
    missing="$(check_elements "$@")"
    if [[ -z "$missing" ]]; then
        echo "$name: all elements are installed"
        exit 0
    fi
    echo "$name: missing element(s): $(echo "$missing" | tr '\n' ' ')" >&2
    exit 1
}

lower_scheme() {  # TEXT: prints a URI with its scheme in lower case (RFC 3986: any case), anything else as it is
    # RTSP://cam/stream is rtsp://cam/stream and UDP://HOST:PORT is udp://HOST:PORT, as GStreamer reads them; the
    # scripts' checks then match the lower-case scheme.
    if [[ "$1" == *://* ]]; then
        local scheme="${1%%://*}"
        echo "${scheme,,}://${1#*://}"
    else
        echo "$1"
    fi
}

input_uri() {  # INPUT: prints the URI uridecodebin plays (a file becomes file:///...); dies on a missing file
    if [[ "$1" == *://* ]]; then
        lower_scheme "$1"
    else
        [[ -f "$1" ]] || die "$1: no such file (give a file or a URI such as rtsp://camera/stream)"
        echo "file://$(uri_path "$(realpath "$1")")"
    fi
}

uri_path() {  # PATH: PATH percent-encoded for a file:// URI, byte by byte (RFC 3986)
    # A file name with '#' (cut off as the URI's fragment), '%' (read as an escape), '?' or a space is a file
    # uridecodebin would not find: "cam #1.mp4" was opened as "cam ". Letters, digits, "/._~-" stay as they are.
    local LC_ALL=C
    local s="$1" out="" c i
    for ((i = 0; i < ${#s}; i++)); do
        c="${s:i:1}"
        case "$c" in
            [A-Za-z0-9/._~-]) out+="$c" ;;
            *) printf -v c '%%%02X' "'$c"; out+="$c" ;;
        esac
    done
    echo "$out"
}

analysis_queue() {  # URI: prints the queue in front of the analysis, one word per line (for mapfile)
    # A live camera does not wait for a slow machine: its frames would pile up without end and the measurements
    # fall further and further behind the road. For a live source the queue keeps a second of frames (25) and
    # drops the oldest beyond that; the elements measure from timestamps, so a dropped frame costs samples only.
    # A file (or anything else) waits for the analysis: a plain queue.
    if is_live_uri "$1"; then
        printf '%s\n' queue leaky=downstream max-size-buffers=25 max-size-bytes=0 max-size-time=0
    else
        printf '%s\n' queue
    fi
}

is_live_uri() {  # URI: true for a camera's stream (rtsp://, udp://, srt://, rtmp://), false for a file or download
    # The scheme in any case (RFC 3986): RTSP://cam/stream is live too, whether input_uri lower-cased it or not.
    case "${1,,}" in
        rtsp://* | rtsps://* | rtspt://* | udp://* | srt://* | rtmp://*) return 0 ;;
        *) return 1 ;;
    esac
}

set_stall_watchdog() {  # URI: sets the array `stall` to (watchdog timeout=MS !) for a live source, else to ()
    # A camera that stops sending (or whose connection fails in a way the source does not report as an error:
    # now and then rtspsrc says "Open failed" and the pipeline waits for ever) ends the run with an error after
    # STALL_TIMEOUT seconds without a frame (default 30; 0: wait for ever), so a service is restarted instead of
    # hanging. Needs GStreamer's watchdog element (gstreamer1.0-plugins-bad); without it, nothing.
    stall=()
    local seconds="${STALL_TIMEOUT:-30}" ms
    [[ "$seconds" =~ ^[0-9]+([.][0-9]+)?$ ]] || die "STALL_TIMEOUT must be a number of seconds, got '$seconds'"
    is_live_uri "$1" || return 0
    ms="$(awk -v s="$seconds" 'BEGIN { printf "%d", s * 1000 }')"
    if [[ "$ms" -gt 0 ]] && gst-inspect-1.0 watchdog >/dev/null 2>&1; then
        stall=(watchdog "timeout=$ms" '!')
    fi
}

keep_earlier_live() {  # URI OUT_DIR: prints the folder a live stream's earlier results in OUT_DIR were moved to
    # A stream cannot be measured again: a recipe started again (a service after a crash or a reboot) into the
    # same OUT_DIR keeps what it measured before in OUT_DIR/earlier-<time of its last vehicle>/ instead of
    # overwriting it. A file can be run again: its results are replaced. Of an output that is a symlink the file
    # it leads to is moved and the link stays for the new run's file (written through it), as `trafficcal run` does.
    local uri="$1" out="$2" kept base n=2 f real
    [[ "${uri,,}" == file://* || ! -s "$out/vehicles.jsonl" ]] && return 0
    base="$out/earlier-$(date -r "$out/vehicles.jsonl" +%Y%m%d-%H%M%S)"
    kept="$base"
    while [[ -e "$kept" ]]; do kept="$base-$n"; n=$((n + 1)); done
    mkdir -p "$kept" || return 1
    for f in vehicles.jsonl vehicles.csv system.json intervals.csv; do
        if [[ -L "$out/$f" ]]; then
            real="$(readlink -f -- "$out/$f")" || continue  # a link that leads nowhere: nothing to keep
            if [[ -f "$real" ]]; then mv -- "$real" "$kept/$f" || return 1; fi
        elif [[ -e "$out/$f" ]]; then
            mv -- "$out/$f" "$kept/" || return 1
        fi
    done
    echo "$kept"
}

launch() {  # [--until FILE] ARGS...: gst-launch-1.0 -e ARGS, with SIGTERM handled as Ctrl-C; returns its exit code
    # gst-launch-1.0 ends the stream on Ctrl-C (-e: every element finishes, a recording is completed) but dies at
    # once on SIGTERM — what systemctl stop, docker stop and Kubernetes send —, and a script killed while it waits
    # leaves it running. Here it runs in the background and both signals reach it as SIGINT; the script waits
    # until it has finished. (A terminal's Ctrl-C reaches it twice, directly and passed on: -e still ends cleanly.)
    # Safe under set -e however it is called (bare or `launch ... || rc=$?`): an interrupted wait does not end the
    # script, which always waits for gst-launch-1.0 and returns its exit code. --until FILE: the stream is ended
    # the same way (EOS) once FILE is not empty (calibrate.sh: vpdetect has saved its calibration).
    # A stop whose end of stream went through (gst-launch-1.0 said "EOS received") succeeds even when the source
    # failed after it, while it was closed (a camera dropping the connection on PAUSE or TEARDOWN): nothing lost.
    local stop=0 until="" said copy tee_pid name
    if [[ "${1:-}" == "--until" ]]; then
        until="$2"
        shift 2
    fi
    said="$(mktemp "${TMPDIR:-/tmp}/gst-launch.XXXXXX")"
    # its output passed on as it comes and kept in $said, by a tee that ignores both signals (so that it outlives
    # gst-launch-1.0's last lines: a tee killed by Ctrl-C would end gst-launch-1.0 by SIGPIPE before the end)
    exec {copy}> >(trap '' INT TERM; exec tee -- "$said")
    tee_pid=$!
    launch_pid=
    trap 'stop=1; [[ -z "$launch_pid" ]] || kill -INT "$launch_pid" 2>/dev/null || true' INT TERM
    # LANGUAGE=en: its messages untranslated, as looked for below
    LANGUAGE=en gst-launch-1.0 -e "$@" >&"$copy" &
    launch_pid=$!
    exec {copy}>&-
    [[ $stop == 0 ]] || kill -INT "$launch_pid" 2>/dev/null || true  # a signal came before its pid was known
    while kill -0 "$launch_pid" 2>/dev/null; do
        if [[ -n "$until" ]]; then
            if [[ -s "$until" ]]; then
                kill -INT "$launch_pid" 2>/dev/null || true
                stop=1
                until=""
            else
                sleep 0.2
            fi
            continue
        fi
        wait "$launch_pid" || true  # returns early when a trapped signal arrives: wait again
    done
    trap - INT TERM
    local rc=0
    wait "$launch_pid" || rc=$?  # its exit code (bash keeps it)
    wait "$tee_pid" 2>/dev/null || true  # its last lines in $said
    if [[ $rc -ne 0 && $stop == 1 ]] && grep -q '^EOS received - stopping pipeline' "$said"; then
        name="${0##*/}"
        echo "${name%.sh}: note: the stream was ended and every output completed before the source failed as it" \
             "was closed (the error above): a clean stop" >&2
        rc=0
    fi
    rm -f -- "$said"
    return "$rc"
}

print_usage() {  # SCRIPT: prints SCRIPT's header comment (the usage and environment it documents), for --help
    local line
    while IFS= read -r line; do
        case "$line" in
            '#!'*) ;;
            '#') echo ;;
            '# '*) echo "${line#'# '}" ;;
            '#'*) echo "${line#'#'}" ;;
            *) break ;;
        esac
    done <"$1"
}
