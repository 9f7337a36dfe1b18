#!/usr/bin/env bash
# Prints the Debian packages that hold the shared libraries BINARY links directly, one
# `name=version` a line, at the versions installed here. The image's runtime stage installs
# exactly these, so the daemon runs on the libraries it was built (and tested) with; apt brings
# their own dependencies. libc6 is left out: every Debian image has it, and pinning it could
# ask apt for a downgrade. Fails when a library is missing or belongs to no package.
# Usage: bash docker/runtime-packages.sh BINARY
set -euo pipefail
bin=${1:?usage: runtime-packages.sh BINARY}

resolved=$(ldd "$bin")
if grep -q "not found" <<<"$resolved"; then
  echo "runtime-packages: $bin: a shared library is missing:" >&2
  grep "not found" <<<"$resolved" >&2
  exit 1
fi

readelf -d "$bin" | sed -n 's/.*Shared library: \[\(.*\)\]$/\1/p' | while read -r soname; do
  path=$(awk -v so="$soname" '$1 == so && $2 == "=>" {print $3}' <<<"$resolved")
  # dpkg knows a file by the path its package installed: try the one ldd names, then the file
  # behind the soname link (and behind the /lib -> /usr/lib merge).
  owner=$(dpkg-query -S "$path" 2>/dev/null || dpkg-query -S "$(realpath "$path")")
  echo "${owner%%:*}"
done | sort -u | while read -r pkg; do
  [ "$pkg" = libc6 ] || dpkg-query -W -f='${Package}=${Version}\n' "$pkg"
done
