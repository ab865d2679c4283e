#!/usr/bin/env bash
# Builds compend's Debian package with cargo-deb: target/debian/compend_VERSION-1_ARCH.deb.
#
#   bash scripts/package.sh              a release build (what a projection PC installs)
#   bash scripts/package.sh --profile dev
#                                        the test profile's build, already there after the
#                                        tests (CI's check of the package, without a release
#                                        build)
#
# Installs cargo-deb (and dpkg-dev, for the library dependencies) when missing. Made from the
# built binary into target/package/: the manual pages (`compend man --dir`), the bash, zsh and
# fish completions (`compend completions`), and the units of systemd/ starting the package's
# /usr/bin/compend. Then: `apt install ./target/debian/*.deb`
# (docs/service.md, "From the Debian package").
set -euo pipefail
cd "$(dirname "$0")/.."

profile=release
case "${1:-}" in
  "") ;;
  --profile) profile="${2:?--profile needs a profile name (dev or release)}" ;;
  *) echo "package: unknown argument $1 (expected --profile dev|release)" >&2; exit 2 ;;
esac
case "$profile" in
  dev) dir=debug ;;
  *) dir="$profile" ;;
esac

sudo=""
[ "$(id -u)" -ne 0 ] && sudo="sudo"
if ! command -v dpkg-shlibdeps >/dev/null 2>&1; then
  export DEBIAN_FRONTEND=noninteractive
  $sudo apt-get update -qq
  $sudo apt-get install -y -qq --no-install-recommends dpkg-dev >/dev/null
fi
# One version, so that the package's build is the same from one day to the next.
cargo_deb_version=3.6.3
if ! cargo deb --version 2>/dev/null | grep -q "$cargo_deb_version"; then
  cargo install --locked cargo-deb --version "$cargo_deb_version"
fi

cargo build --locked --profile "$profile" --bin compend
target="${CARGO_TARGET_DIR:-target}"
bin="$target/$dir/compend"

out="$target/package"
rm -rf "$out"
mkdir -p "$out/man" "$out/completions" "$out/system" "$out/user"
"$bin" man --dir "$out/man"
"$bin" completions bash >"$out/completions/compend.bash"
"$bin" completions zsh >"$out/completions/_compend"
"$bin" completions fish >"$out/completions/compend.fish"
# The units as the package installs them: the binary in /usr/bin. The system unit's name is the
# package's, as cargo-deb's systemd-units expects; the user unit goes to the user manager's
# folder under the same name.
# (systemd/compend.service starts /usr/local/bin/compend, the user unit ~/.local/bin/compend.)
for unit in compend compend-user; do
  where=system from=/usr/local/bin/compend
  [ "$unit" = compend-user ] && where=user from=%h/.local/bin/compend
  grep -q "^ExecStart=$from " "systemd/$unit.service" || {
    echo "package: systemd/$unit.service does not start $from" >&2
    exit 1
  }
  sed "s#$from#/usr/bin/compend#g" "systemd/$unit.service" >"$out/$where/compend.service"
done

# (cargo-deb warns that a dev profile will not be accepted in a later version: the version is
# pinned above, and the check of a dev build is CI's, not a package anyone installs.)
cargo deb --no-build --profile "$profile" --locked
ls -l "$target"/debian/*.deb
