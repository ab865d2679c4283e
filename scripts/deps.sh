#!/usr/bin/env bash
# Installs the Debian packages compend needs to build and test, only those that are missing.
#   mesa-vulkan-drivers, libvulkan1: software Vulkan (lavapipe) for the wgpu pass without a GPU
#   xvfb: a virtual X display for the projector-window tests
#   xserver-xorg-core, xserver-xorg-video-dummy, x11-xserver-utils: an X server with several
#     monitors (Xorg's dummy driver, its outputs set by xrandr) for a set's windows
#   libclang-dev: bindgen, used by the V4L2 camera crates at build time
#   imagemagick: screenshots of the virtual display in tests
#   systemd, procps: systemd-analyze and /bin/kill (ExecReload=), to verify the units in systemd/
#   GStreamer, for films, streams, screens and sound (docs/usage.md, "Media"):
#     libgstreamer1.0-dev, libgstreamer-plugins-base1.0-dev: the headers gstreamer-rs builds on
#     gstreamer1.0-plugins-base: playbin, videoconvert, appsink/appsrc, Ogg/Theora/Vorbis/Opus
#     gstreamer1.0-plugins-good: MP4/MOV and Matroska/WebM, VP8/VP9 (libvpx), ximagesrc,
#       v4l2sink, PulseAudio
#     gstreamer1.0-plugins-bad: OpenH264 (H.264 encode and decode), AV1 (aom), shmsink, SRT
#     gstreamer1.0-libav: FFmpeg's decoders: H.264, H.265, ProRes, HAP, AAC, AC-3, ...
#     gstreamer1.0-alsa: alsasink, the sound card when no sound server runs
#     gstreamer1.0-tools: gst-launch-1.0 and gst-inspect-1.0, to try a pipeline by hand
#   chromium, chromium-driver: the console's page tested in a real browser (WebDriver)
#   openssl: a certificate authority and a certificate for the console's HTTPS test
set -euo pipefail
pkgs=(mesa-vulkan-drivers libvulkan1 xvfb xserver-xorg-core xserver-xorg-video-dummy
  x11-xserver-utils libclang-dev imagemagick systemd procps
  libgstreamer1.0-dev libgstreamer-plugins-base1.0-dev gstreamer1.0-plugins-base
  gstreamer1.0-plugins-good gstreamer1.0-plugins-bad gstreamer1.0-libav gstreamer1.0-alsa
  gstreamer1.0-tools chromium chromium-driver openssl)
missing=()
for p in "${pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
[ ${#missing[@]} -eq 0 ] && exit 0
echo "compend: installing missing system packages: ${missing[*]}" >&2
sudo=""
[ "$(id -u)" -ne 0 ] && sudo="sudo"
export DEBIAN_FRONTEND=noninteractive
$sudo apt-get update -qq
$sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
