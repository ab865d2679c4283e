#!/usr/bin/env bash
# Installs the Debian package that scripts/package.sh built (target/debian/compend_*.deb) on this
# machine with dpkg, checks what it installed, then removes and purges it:
#   - /usr/bin/compend runs and says its version; its manual pages and completions are there;
#   - the compend system user exists, in the video group;
#   - the installed units pass `systemd-analyze verify` as installed (ExecStart=/usr/bin/compend),
#     and are not enabled: the configuration is edited first;
#   - /etc/compend/compend.toml is a conffile that `compend config check` accepts;
#   - removal takes the binary and keeps the configuration; a purge takes the configuration;
#     the user stays (Debian's rule for system users, and /var/lib/compend holds models).
# Needs root (or sudo). CI runs it on its throwaway machine (.ci/run). On a machine where the
# package is installed, or /etc/compend holds a configuration, it refuses (exit 2): its purge would
# take a configuration it did not make.
set -euo pipefail
cd "$(dirname "$0")/.."

sudo=""
[ "$(id -u)" -ne 0 ] && sudo="sudo"
target="${CARGO_TARGET_DIR:-target}"
debs=("$target"/debian/compend_*.deb)
[ -f "${debs[0]}" ] || { echo "check-package: no package in $target/debian (run scripts/package.sh)" >&2; exit 1; }
deb="$(ls -t "${debs[@]}" | head -n 1)"

fail() { echo "check-package: $*" >&2; exit 1; }

if dpkg-query -W -f='${Status}' compend 2>/dev/null | grep -q "installed"; then
  echo "check-package: the compend package is installed here; its test would remove it and purge its configuration (run it on a throwaway machine)" >&2
  exit 2
fi
if [ -e /etc/compend ]; then
  echo "check-package: /etc/compend exists; the package's purge would take a configuration this check did not make (run it on a throwaway machine)" >&2
  exit 2
fi

$sudo dpkg -i "$deb"
/usr/bin/compend --version | grep -q "^compend " || fail "/usr/bin/compend --version"
for f in /usr/share/man/man1/compend.1 /usr/share/man/man1/compend-calibrate.1 \
  /usr/share/bash-completion/completions/compend /usr/share/zsh/vendor-completions/_compend \
  /usr/share/fish/vendor_completions.d/compend.fish /usr/lib/systemd/user/compend.service; do
  [ -s "$f" ] || [ -s "$f.gz" ] || fail "$f is not installed"
done
id compend >/dev/null || fail "no compend user"
id -nG compend | tr ' ' '\n' | grep -qx video || fail "compend is not in the video group"

unit=""
for d in /usr/lib/systemd/system /lib/systemd/system; do
  [ -f "$d/compend.service" ] && unit="$d/compend.service" && break
done
[ -n "$unit" ] || fail "compend.service is not installed"
grep -q '^ExecStart=/usr/bin/compend serve ' "$unit" || fail "$unit does not start /usr/bin/compend"
runtime="$(mktemp -d)"
trap 'rm -rf "$runtime"' EXIT
chmod 0700 "$runtime"
for scope in system user; do
  file="$unit" flag=()
  [ "$scope" = user ] && file=/usr/lib/systemd/user/compend.service flag=(--user)
  out="$(XDG_RUNTIME_DIR="$runtime" SYSTEMD_LOG_COLOR=0 \
    systemd-analyze "${flag[@]}" verify --man=no --recursive-errors=yes "$file" 2>&1)" ||
    fail "systemd-analyze verify $file failed: $out"
  [ -z "$out" ] || fail "systemd-analyze verify $file said: $out"
  echo "check-package: $file ($scope): verified"
done
if [ -e /etc/systemd/system/multi-user.target.wants/compend.service ]; then
  fail "the package enabled compend.service before its configuration was edited"
fi

conf=/etc/compend/compend.toml
dpkg-query -W -f='${Conffiles}\n' compend | grep -q " $conf " || fail "$conf is not a conffile"
check="$(/usr/bin/compend config check "$conf")" || fail "compend config check $conf: $check"
echo "$check" | grep -q 'kind = "camera"' || fail "config check does not name the next step: $check"

$sudo dpkg -r compend
[ ! -e /usr/bin/compend ] || fail "removal left /usr/bin/compend"
[ -f "$conf" ] || fail "removal took $conf (only a purge does)"
$sudo dpkg -P compend
[ ! -e "$conf" ] || fail "the purge left $conf"
id compend >/dev/null || fail "the purge removed the compend user"
echo "check-package: $(basename "$deb") installs, verifies, removes and purges"
