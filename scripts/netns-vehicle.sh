#!/usr/bin/env bash
# A two-unit vehicle and a fleet server as three network namespaces on this machine (root).
#
#   scripts/netns-vehicle.sh up RUN_ID        create the namespaces, links and addresses
#   scripts/netns-vehicle.sh down RUN_ID      stop what still runs in them and delete them (idempotent)
#   scripts/netns-vehicle.sh cut RUN_ID       take the sensing<->estimation link down (both ends)
#   scripts/netns-vehicle.sh restore RUN_ID   bring it back up
#   scripts/netns-vehicle.sh cut-fleet RUN_ID / restore-fleet RUN_ID   the same for sensing<->fleet
#   scripts/netns-vehicle.sh exec RUN_ID UNIT CMD...   run CMD in UNIT (sense | est | fleet)
#   scripts/netns-vehicle.sh names RUN_ID     print the three namespace names
#
# Topology (point-to-point veth links, no bridge, no forwarding; every address lives only
# inside these namespaces, so no traffic ever leaves them):
#
#   [fleet]  10.99.2.2 ──── 10.99.2.1  [sense]  10.99.1.1 ──── 10.99.1.2  [est]
#   fleet router            vehicle router,                     unit router, observer,
#                           gateway, normal-force, vehicle      soil-strength, ocp
#
# RUN_ID: 1-6 characters [a-z0-9], unique per run (interface names must stay <= 15 chars).
set -euo pipefail

die() { echo "netns-vehicle: $*" >&2; exit 2; }
[[ $# -ge 2 ]] || die "usage: $0 up|down|cut|restore|exec|names RUN_ID [UNIT CMD...]"
cmd="$1"; id="$2"; shift 2
[[ "$id" =~ ^[a-z0-9]{1,6}$ ]] || die "RUN_ID '$id' must be 1-6 characters [a-z0-9]"

sysctl_conf="$(cd "$(dirname "$0")/.." && pwd)/deploy/sysctl/90-soilocp.conf"
ns_fleet="soilocp-$id-fleet"; ns_sense="soilocp-$id-sense"; ns_est="soilocp-$id-est"
# veth ends: <unit-letter><id><peer-letter>, e.g. "sab12e" = on sense, towards est
if_se="s${id}e"; if_es="e${id}s"; if_sf="s${id}f"; if_fs="f${id}s"

ns_of() {
    case "$1" in
        sense) echo "$ns_sense" ;; est) echo "$ns_est" ;; fleet) echo "$ns_fleet" ;;
        *) die "unknown unit '$1' (sense | est | fleet)" ;;
    esac
}

down() {
    local ns pid
    for ns in "$ns_fleet" "$ns_sense" "$ns_est"; do
        ip netns list | grep -qw "^$ns" || continue
        # Only processes inside our own namespaces, by id: what the test started there.
        for pid in $(ip netns pids "$ns" 2>/dev/null); do kill -TERM "$pid" 2>/dev/null || true; done
        sleep 0.3
        for pid in $(ip netns pids "$ns" 2>/dev/null); do kill -KILL "$pid" 2>/dev/null || true; done
        ip netns del "$ns" 2>/dev/null || true
    done
    # a veth end left in the root namespace by an interrupted `up`
    for dev in "$if_se" "$if_es" "$if_sf" "$if_fs"; do ip link del "$dev" 2>/dev/null || true; done
}

up() {
    down
    local ns
    for ns in "$ns_fleet" "$ns_sense" "$ns_est"; do
        ip netns add "$ns"
        ip -n "$ns" link set lo up
    done
    ip link add "$if_se" netns "$ns_sense" type veth peer name "$if_es" netns "$ns_est"
    ip link add "$if_sf" netns "$ns_sense" type veth peer name "$if_fs" netns "$ns_fleet"
    ip -n "$ns_sense" addr add 10.99.1.1/24 dev "$if_se"
    ip -n "$ns_est"   addr add 10.99.1.2/24 dev "$if_es"
    ip -n "$ns_sense" addr add 10.99.2.1/24 dev "$if_sf"
    ip -n "$ns_fleet" addr add 10.99.2.2/24 dev "$if_fs"
    # the kernel settings every host of a fleet gets (deploy/sysctl/90-soilocp.conf: a dead TCP
    # connection is given up after ~12.6 s, so a router reconnects as soon as a long outage ends)
    for ns in "$ns_fleet" "$ns_sense" "$ns_est"; do
        ip netns exec "$ns" sysctl -q -p "$sysctl_conf" >/dev/null
    done
    ip -n "$ns_sense" link set "$if_se" up
    ip -n "$ns_est"   link set "$if_es" up
    ip -n "$ns_sense" link set "$if_sf" up
    ip -n "$ns_fleet" link set "$if_fs" up
    # wait until every link end reports carrier (veth carrier comes up asynchronously)
    local i
    for i in $(seq 50); do
        if ip -n "$ns_sense" -o link show dev "$if_se" | grep -q 'state UP' &&
           ip -n "$ns_est" -o link show dev "$if_es" | grep -q 'state UP' &&
           ip -n "$ns_sense" -o link show dev "$if_sf" | grep -q 'state UP' &&
           ip -n "$ns_fleet" -o link show dev "$if_fs" | grep -q 'state UP'; then
            return 0
        fi
        sleep 0.1
    done
    die "links did not come up"
}

case "$cmd" in
    up) trap 'down' ERR; up ;;
    down) down ;;
    cut) ip -n "$ns_sense" link set "$if_se" down; ip -n "$ns_est" link set "$if_es" down ;;
    restore) ip -n "$ns_sense" link set "$if_se" up; ip -n "$ns_est" link set "$if_es" up ;;
    cut-fleet) ip -n "$ns_sense" link set "$if_sf" down; ip -n "$ns_fleet" link set "$if_fs" down ;;
    restore-fleet) ip -n "$ns_sense" link set "$if_sf" up; ip -n "$ns_fleet" link set "$if_fs" up ;;
    exec) [[ $# -ge 2 ]] || die "exec needs UNIT CMD..."; ns="$(ns_of "$1")"; shift; exec ip netns exec "$ns" "$@" ;;
    names) echo "$ns_fleet $ns_sense $ns_est" ;;
    *) die "unknown command '$cmd'" ;;
esac
