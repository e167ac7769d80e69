#!/usr/bin/env bash
# Three "machines" on one Linux box, for rehearsing deploy/README.md without a cluster.
#
#   sudo deploy/netns-lab.sh up      # namespaces nmae-h0 (10.231.0.1), nmae-h1 (.2), nmae-h2 (.3)
#   sudo ip netns exec nmae-h1 <command>   # run <command> "on machine 1"
#   sudo deploy/netns-lab.sh down
#
# Each machine is a network namespace with its own loopback and one address on a private
# bridge (kept in a fourth namespace, nmae-lan), so a server bound to 127.0.0.1 on h1 is
# unreachable from h0 exactly as on real machines. Nothing is routed to or from the host's
# own network. Needs root (CAP_NET_ADMIN) and iproute2.
set -euo pipefail
HOSTS=(nmae-h0 nmae-h1 nmae-h2)
NET=10.231.0

up() {
  ip netns add nmae-lan
  ip -n nmae-lan link add br0 type bridge
  ip -n nmae-lan link set br0 up
  for i in "${!HOSTS[@]}"; do
    ns=${HOSTS[$i]}
    ip netns add "$ns"
    ip -n "$ns" link set lo up
    ip link add "veth$i" netns "$ns" type veth peer name "port$i" netns nmae-lan
    ip -n nmae-lan link set "port$i" master br0 up
    ip -n "$ns" addr add "$NET.$((i + 1))/24" dev "veth$i"
    ip -n "$ns" link set "veth$i" up
  done
  for i in "${!HOSTS[@]}"; do
    echo "${HOSTS[$i]}: $NET.$((i + 1))"
  done
}

down() {
  for ns in "${HOSTS[@]}" nmae-lan; do
    ip netns del "$ns" 2>/dev/null || true
  done
}

case "${1:-}" in
  up) up ;;
  down) down ;;
  *) echo "usage: $0 up|down" >&2; exit 2 ;;
esac
