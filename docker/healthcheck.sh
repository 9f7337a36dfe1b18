#!/bin/bash
# The image's health check: exits 0 when the daemon on this host answers GET /healthz with 200.
# Bash alone (its /dev/tcp) speaks the request, so the image needs no HTTP client; /healthz takes
# no lock, so a daemon busy rendering still passes. Usage: healthcheck.sh [PORT] (default 8080)
set -eu
port=${1:-8080}
exec 3<>"/dev/tcp/127.0.0.1/$port"
printf 'GET /healthz HTTP/1.0\r\nHost: 127.0.0.1\r\n\r\n' >&3
IFS= read -r -t 5 status <&3
[[ $status == HTTP/1.[01]" 200 "* ]]
