#!/bin/bash
# The four-host walk-through of docs/deploy.md on one machine: a folder per host, loopback addresses,
# each node started with exactly the ExecStart= line of the unit `zdrone service` printed for it
# (%L and %S pointing into the work folder, ZDRONE_STATE_DIR as the unit sets it), and the built-in
# simulator as the flight controller. Ends with the drone's hand-overs; stops everything it started.
#   docs/deploy-loopback.sh [WORK_DIR]        (ZDRONE=path/to/zdrone to use another one)
set -euo pipefail
Z=${ZDRONE:-$(command -v zdrone)}
W=$(realpath -m "${1:-/tmp/zdrone-deploy}"); rm -rf "$W"; mkdir -p "$W/log" "$W/state"; cd "$W"
free() { python3 -c "import socket; s=socket.socket(socket.AF_INET, socket.$1); s.bind(('127.0.0.1',0)); print(s.getsockname()[1])"; }
EP=tls/127.0.0.1:$(free SOCK_STREAM); SIM=$(free SOCK_DGRAM)
PIDS=(); trap 'kill "${PIDS[@]}" 2>/dev/null || true' EXIT
"$Z" fleet init --dir issuer/fleet --tls > /dev/null                     # the issuer: every secret, the CA key
for n in router d1 A B; do
  "$Z" fleet export $n --dir issuer/fleet --out hosts/$n/etc/zdrone/$n > /dev/null
  shown=$("$Z" fleet show --dir hosts/$n/etc/zdrone/$n --check-secrets); echo "${shown%%$'\n'*}"
done
"$Z" service router --bundle hosts/router/etc/zdrone/router --router $EP > router.service
"$Z" service d1 --bundle hosts/d1/etc/zdrone/d1 --router $EP --vehicle udpout:127.0.0.1:$SIM > d1.service
"$Z" service B --bundle hosts/B/etc/zdrone/B --router $EP --node-options="--command-rate 5" > B.service
"$Z" service A --bundle hosts/A/etc/zdrone/A --router $EP --node-options="--pair --mission reference --command-rate 5" > A.service
start() {  # a unit's ExecStart, in its state directory, with its environment
  mkdir -p "$W/log/zdrone-$1" "$W/state/zdrone-$1"
  local cmd; cmd=$(sed -n "s|^ExecStart=||p" $1.service | sed "s|%L|$W/log|g; s|%S|$W/state|g")
  (cd "$W/state/zdrone-$1" && ZDRONE_STATE_DIR="$W/state/zdrone-$1" exec $cmd > "$W/log/$1.out" 2>&1) & PIDS+=($!)
}
start router; sleep 2
"$Z" sim --mavlink udpin:127.0.0.1:$SIM --speedup 4 > "$W/log/sim.out" 2>&1 & PIDS+=($!)
sleep 1; start d1; sleep 3; start B; sleep 2; start A
for _ in $(seq 1 180); do  # until the hand-back to A
  grep -q '"type":"handover_complete".*"from":"B"' "$W/log/zdrone-d1/events.jsonl" 2>/dev/null && break; sleep 1
done
sleep 5
grep -o '"type":"handover_complete"[^}]*"from":"[A-Z]","to":"[A-Z]"' "$W/log/zdrone-d1/events.jsonl"
