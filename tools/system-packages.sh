#!/bin/sh
# Debian packages some features and their tests need: Graphviz `dot` (olti diagrams) and Chromium
# (the headless-browser test of the Meshcat view). Installs them when apt-get can (root or
# password-less sudo); otherwise says so and carries on: the tests that need them are skipped
# with the reason. Never fails the set-up line it is part of.
need=""
command -v dot >/dev/null 2>&1 || need="$need graphviz"
command -v chromium >/dev/null 2>&1 || need="$need chromium"
[ -z "$need" ] && exit 0
if [ "$(id -u)" = 0 ]; then sudo=""; elif sudo -n true 2>/dev/null; then sudo="sudo -n"; else sudo=none; fi
if [ "$sudo" = none ] || ! command -v apt-get >/dev/null 2>&1; then
    echo "system-packages: cannot install$need here (no apt-get or no root); tests needing them will be skipped" >&2
    exit 0
fi
echo "system-packages: installing$need (Debian packages)" >&2
{ $sudo apt-get update -qq && DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends $need; } \
    >/tmp/olti-system-packages.log 2>&1 \
    || echo "system-packages: apt-get failed (see /tmp/olti-system-packages.log); tests needing$need will be skipped" >&2
exit 0
