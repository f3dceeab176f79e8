#!/usr/bin/env bash
# Make the real services the tests use available: the mosquitto binary (tests start their own broker
# on a free port) and a local PostgreSQL server (tests create and drop their own database).
# Installs from Debian's packages when running as root and something is missing; never fails the build
# by itself: the tests report a missing service (a failure under CI=true, a skip elsewhere).
set -u
have() { command -v "$1" >/dev/null 2>&1; }
can_install() { [ "$(id -u)" = 0 ] && have apt-get; }
apt_updated=0
apt_install() {
  if can_install; then
    [ "$apt_updated" = 1 ] || { apt-get update -qq >/dev/null 2>&1; apt_updated=1; }
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$@" >/dev/null 2>&1 \
      || echo "ensure-services: could not install $*" >&2
  else
    echo "ensure-services: $* missing; install it (apt-get install $*)" >&2
  fi
}

# mosquitto: the binary only (tests/iotools/test_mqtt_live.py starts a private broker)
if ! have mosquitto && [ ! -x /usr/sbin/mosquitto ]; then apt_install mosquitto; fi

# chromium: headless browser for the web dashboard's end-to-end test (tests/web/test_browser.py)
if ! have chromium && [ ! -x /usr/bin/chromium ]; then apt_install chromium chromium-driver; fi

# PostgreSQL: reach CNCTWIN_PG_URL if set, else the local default; start the local cluster if down
if [ -z "${CNCTWIN_PG_URL:-}" ]; then
  if ! have pg_isready && ! ls /usr/lib/postgresql/*/bin/pg_ctl >/dev/null 2>&1; then
    apt_install postgresql
  fi
  if have pg_isready && ! pg_isready -q -h 127.0.0.1 -p 5432; then
    if have pg_ctlcluster && ls /etc/postgresql >/dev/null 2>&1; then
      for v in $(ls /etc/postgresql); do
        pg_ctlcluster --skip-systemctl-redirect "$v" main start >/dev/null 2>&1 || true
      done
    fi
    pg_isready -q -h 127.0.0.1 -p 5432 \
      || echo "ensure-services: PostgreSQL is not reachable on 127.0.0.1:5432" >&2
  fi
fi
# node-opcua: an OPC UA client cnctwin did not write, for the interoperability test
# (tests/interop); Node.js and npm from Debian, the package from the npm registry, pinned,
# into .node/ of the checkout
if ! have node || ! have npm; then apt_install nodejs npm; fi
NODE_OPCUA=2.186.4
if have npm && [ ! -f .node/node_modules/node-opcua-client/package.json ] \
    || ! grep -q "\"version\": \"$NODE_OPCUA\"" .node/node_modules/node-opcua-client/package.json 2>/dev/null; then
  if have npm; then
    npm install --silent --no-audit --no-fund --prefix .node "node-opcua-client@$NODE_OPCUA" \
      >/dev/null 2>&1 || echo "ensure-services: npm could not install node-opcua-client" >&2
  fi
fi
exit 0
