#!/usr/bin/env bash
# Checks the systemd units with `systemd-analyze verify`: fails on anything it prints (unknown
# keys, bad values, missing dependencies or executables), not only on its exit status.
#
#   bash scripts/verify-units.sh            systemd/compend.service (system manager) and
#                                           systemd/compend-user.service (user manager), then a
#                                           self-check that a misspelt key is caught
#   bash scripts/verify-units.sh FILE...    the given unit files; a name ending in -user.service
#                                           is checked as a user unit, any other as a system unit
#
# Needs no running systemd (CI runs it in a Debian container without one): verify loads the units
# into an offline manager. systemd-analyze checks that each Exec*= command exists, so each unit is
# checked as a copy in a temporary directory whose compend command points at the built binary
# (target/debug/compend) or, before a build, /bin/true. The user manager wants a runtime
# directory: a private temporary one stands in for $XDG_RUNTIME_DIR.
set -euo pipefail
cd "$(dirname "$0")/.."

# systemd-analyze (package systemd) and /bin/kill (procps, named by ExecReload=): scripts/deps.sh
# installs both; this covers running the script on its own.
if ! command -v systemd-analyze >/dev/null 2>&1 || [ ! -x /bin/kill ]; then
  echo "verify-units: systemd-analyze or /bin/kill is missing; installing systemd and procps" >&2
  sudo=""
  [ "$(id -u)" -ne 0 ] && sudo="sudo"
  export DEBIAN_FRONTEND=noninteractive
  $sudo apt-get update -qq
  $sudo apt-get install -y -qq --no-install-recommends systemd procps >/dev/null
fi

bin="${CARGO_TARGET_DIR:-target}/debug/compend"
if [ -x "$bin" ]; then
  bin="$(cd "$(dirname "$bin")" && pwd)/compend"
else
  bin=/bin/true
fi

tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
mkdir -m 0700 "$tmp/runtime"

# check FILE: verify one unit; prints what systemd-analyze said and returns 1 if it said anything
# or exited non-zero.
n=0
check() {
  local file="$1" name scope dir out rc
  [ -f "$file" ] || { echo "verify-units: $file: no such file" >&2; return 1; }
  name="$(basename "$file")"
  scope=(); [[ "$name" == *-user.service ]] && scope=(--user)
  n=$((n + 1))
  dir="$tmp/$n"
  mkdir "$dir"
  # Point every Exec*= line that runs compend (any prefix such as - or @, any install path) at
  # a real executable; the arguments stay as they are.
  sed -E "s#^(Exec[A-Za-z]*=[-@:+!]*)[^[:space:]]*/compend([[:space:]]|\$)#\\1${bin}\\2#" \
    "$file" >"$dir/$name" || return 1
  rc=0
  # --recursive-errors=yes: a non-zero exit for warnings too (=no would also skip the check that
  # required units exist); --man=no: no man(1) lookups for Documentation=. No colours, so the
  # output compares cleanly. Anything printed at all counts as a failure.
  out="$(XDG_RUNTIME_DIR="$tmp/runtime" SYSTEMD_LOG_COLOR=0 \
    systemd-analyze "${scope[@]}" verify --man=no --recursive-errors=yes "$dir/$name" 2>&1)" || rc=$?
  if [ "$rc" -ne 0 ] || [ -n "$out" ]; then
    echo "verify-units: $file (${scope[*]:---system}): systemd-analyze verify exited $rc and said:" >&2
    # Show the copy's path as the original's.
    printf '%s\n' "${out:-(nothing)}" | sed "s#$dir/#$(dirname "$file")/#g" >&2
    return 1
  fi
  echo "verify-units: $file (${scope[*]:---system}): ok"
}

status=0
if [ $# -gt 0 ]; then
  for f in "$@"; do check "$f" || status=1; done
  exit "$status"
fi

check systemd/compend.service || status=1
check systemd/compend-user.service || status=1

# Self-check: a misspelt key must make the check fail, or a quiet systemd-analyze (another
# version, another output channel) would let every unit pass.
sed 's/^Restart=on-failure$/Restrat=on-failure/' systemd/compend.service >"$tmp/compend.service"
grep -q '^Restrat=' "$tmp/compend.service" || { echo "verify-units: self-check: no Restart= line to misspell" >&2; exit 1; }
if check "$tmp/compend.service" 2>"$tmp/selfcheck.log" >/dev/null; then
  echo "verify-units: self-check failed: a unit with 'Restrat=on-failure' passed" >&2
  status=1
elif ! grep -q "Restrat" "$tmp/selfcheck.log"; then
  echo "verify-units: self-check failed: the misspelt key was rejected without being named:" >&2
  cat "$tmp/selfcheck.log" >&2
  status=1
else
  echo "verify-units: self-check: a misspelt key (Restrat=) is caught"
fi

[ "$status" -eq 0 ] && echo "verify-units: all units verified (compend command checked as $bin)"
exit "$status"
