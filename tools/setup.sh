#!/usr/bin/env bash
# Idempotent install: Debian packages, the venv (from /usr/bin/python3 with
# --system-site-packages), pinned pip packages, and generated messages.
# A warm rerun only checks and takes about a second.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
venv="$root/.venv"
t0=$(date +%s%N)

# 1. Debian packages
# TEMOTO_APT_LIST names another list (the test of the no-root message uses it)
mapfile -t pkgs < <(grep -v -E '^\s*(#|$)' "${TEMOTO_APT_LIST:-tools/apt-packages.txt}")
installed=" $(dpkg-query -W -f='${db:Status-Abbrev} ${Package}\n' "${pkgs[@]}" 2>/dev/null | awk '$1 == "ii" {printf "%s ", $2}' || true)"
missing=""
for p in "${pkgs[@]}"; do
  case "$installed" in *" $p "*) ;; *) missing="$missing $p" ;; esac
done
if [ -n "$missing" ]; then
  if [ "$(id -u)" -ne 0 ]; then
    echo "error: Debian packages are missing and installing them needs root: run 'sudo make setup' (missing:$missing)" >&2
    exit 1
  fi
  echo "setup: installing Debian packages:$missing"
  apt-get update -qq
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${pkgs[@]}" >/dev/null
fi

# 1b. Debian packages from the release's backports suite (tools/apt-backports.txt says why), from the same
# archive as the system's own sources: no host is named here
mapfile -t bpo < <(grep -v -E '^\s*(#|$)' tools/apt-backports.txt)
suite="$(. /etc/os-release && echo "${VERSION_CODENAME:-bookworm}")-backports"
stale=""
for p in "${bpo[@]}"; do
  case "$(dpkg-query -W -f='${Version}' "$p" 2>/dev/null || true)" in *~bpo*) ;; *) stale="$stale $p" ;; esac
done
if [ -n "$stale" ]; then
  if [ "$(id -u)" -ne 0 ]; then
    echo "error: packages from $suite are missing and installing them needs root: run 'sudo make setup' (missing:$stale)" >&2
    exit 1
  fi
  if ! grep -rqs -- "$suite" /etc/apt/sources.list /etc/apt/sources.list.d/; then
    uri=$(awk '$1 == "URIs:" {print $2; exit}' /etc/apt/sources.list.d/debian.sources 2>/dev/null || true)
    [ -n "$uri" ] || uri=$(awk '$1 == "deb" && $2 ~ /^http/ {print $2; exit}' /etc/apt/sources.list 2>/dev/null || true)
    if [ -z "$uri" ]; then
      echo "error: cannot find the Debian archive in the apt sources to add $suite from" >&2
      exit 1
    fi
    printf 'Types: deb\nURIs: %s\nSuites: %s\nComponents: main\nSigned-By: /usr/share/keyrings/debian-archive-keyring.gpg\n' \
      "$uri" "$suite" > /etc/apt/sources.list.d/temoto-backports.sources
  fi
  echo "setup: installing from $suite:$stale"
  apt-get update -qq
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends -t "$suite" "${bpo[@]}" >/dev/null
fi

# 2. venv from Debian's interpreter, so that Debian's rospy and pip packages meet
if [ ! -x "$venv/bin/python" ]; then
  echo "setup: creating the venv from /usr/bin/python3..."
  /usr/bin/python3 -m venv --system-site-packages "$venv"
fi

# 3. pinned pip packages (requirements.txt is a complete lock: installed with --no-deps)
want=$(sha256sum requirements.txt setup.py | sha256sum | cut -d' ' -f1)
if [ "$(cat "$venv/.requirements.sha" 2>/dev/null)" != "$want" ]; then
  echo "setup: installing pinned pip packages..."
  log="$venv/pip-install.log"
  { "$venv/bin/pip" install --disable-pip-version-check --no-deps -r requirements.txt &&
    "$venv/bin/pip" install --disable-pip-version-check --no-deps --no-build-isolation -e . ; } >"$log" 2>&1 ||
    { tail -20 "$log" >&2; echo "error: pip install failed; full log in $log" >&2; exit 1; }
  echo "$want" > "$venv/.requirements.sha"
fi

# 4. messages
"$venv/bin/python" tools/gen_msgs.py "$root" >/dev/null

ms=$(( ($(date +%s%N) - t0) / 1000000 ))
printf 'setup: ready in %d.%03d s\n' $((ms / 1000)) $((ms % 1000))
