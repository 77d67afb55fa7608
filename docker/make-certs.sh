#!/usr/bin/env bash
# Make the secrets of one camnet deployment: a CA, the router's TLS certificate, and the
# password the nodes log in with.
#
#   docker/make-certs.sh [-o DIR] [-f] ROUTER_HOST [OTHER_NAME...]
#
# ROUTER_HOST is the name or IP address the nodes connect to (localhost on a single host);
# OTHER_NAMEs are further names of the router host for its certificate. localhost and
# 127.0.0.1 are always included. Writes into DIR (default docker/secrets):
#
#   ca.pem, ca-key.pem       the CA; keep ca-key.pem off the rig (it signs new certificates)
#   router.pem, router-key.pem   the router's certificate and key   -> router host only
#   passwords.txt            the router's "user:password" dictionary -> router host only
#   node.json5               docker/zenoh/node.json5 with ROUTER_HOST and the password
#                            -> every host that runs camnet nodes, with ca.pem
#
# DIR is made private (0700) and the private keys and the dictionary are 0600. node.json5
# and the certificates are 0644 so that the containers' non-root user can read them
# through the bind mount; the private DIR keeps other users of the host out.
set -euo pipefail

here=$(cd "$(dirname "$0")" && pwd)
out="$here/secrets"
force=0
user=camnet
usage="usage: $0 [-o DIR] [-f] ROUTER_HOST [OTHER_NAME...]"

while getopts "o:fh" opt; do
  case $opt in
    o) out=$OPTARG ;;
    f) force=1 ;;
    h) echo "$usage"; exit 0 ;;
    *) echo "$usage" >&2; exit 2 ;;
  esac
done
shift $((OPTIND - 1))
if [ $# -lt 1 ]; then
  echo "make-certs: error: ROUTER_HOST missing; $usage" >&2
  exit 2
fi
router_host=$1
endpoint="tls/$router_host:7447"
if [[ $router_host == *:* ]]; then
  endpoint="tls/[$router_host]:7447"  # an IPv6 address
fi
if ! command -v openssl >/dev/null; then
  echo "make-certs: error: openssl not found (Debian: apt-get install openssl)" >&2
  exit 2
fi
if [ -e "$out/ca-key.pem" ] && [ $force = 0 ]; then
  echo "make-certs: error: $out already holds a CA; give -f to replace every secret in it" >&2
  exit 2
fi

# Subject alternative names: the router's names as clients will dial them.
sans="DNS:localhost,IP:127.0.0.1"
for name in "$@"; do
  if [[ $name == localhost || $name == 127.0.0.1 ]]; then
    continue
  elif [[ $name =~ ^[0-9.]+$ || $name == *:* ]]; then
    sans="$sans,IP:$name"
  else
    sans="$sans,DNS:$name"
  fi
done

# Build everything in a scratch directory and move it into place at the end: an error
# halfway leaves DIR as it was.
mkdir -p "$out"
chmod 700 "$out"
tmp=$(mktemp -d "$out/.make-certs.XXXXXX")
trap 'rm -rf "$tmp"' EXIT
umask 077

run_openssl() {
  openssl "$@" 2>"$tmp/openssl.log" \
    || { echo "make-certs: error: openssl $1: $(tail -n 1 "$tmp/openssl.log")" >&2; exit 1; }
}

run_openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes -days 3650 \
  -subj "/CN=camnet deployment CA" -addext "basicConstraints=critical,CA:TRUE" \
  -addext "keyUsage=critical,keyCertSign,cRLSign" -keyout "$tmp/ca-key.pem" -out "$tmp/ca.pem"
run_openssl req -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes \
  -subj "/CN=$router_host" -keyout "$tmp/router-key.pem" -out "$tmp/router.csr"
printf '%s\n' "subjectAltName=$sans" "basicConstraints=critical,CA:FALSE" \
  "keyUsage=critical,digitalSignature" "extendedKeyUsage=serverAuth" > "$tmp/router.ext"
run_openssl x509 -req -in "$tmp/router.csr" -CA "$tmp/ca.pem" -CAkey "$tmp/ca-key.pem" \
  -CAcreateserial -days 825 -extfile "$tmp/router.ext" -out "$tmp/router.pem"
rm "$tmp/router.csr" "$tmp/router.ext" "$tmp/ca.srl" "$tmp/openssl.log"

# Letters and digits only: the password goes into a JSON5 string and a "user:password" line.
password=$(openssl rand -base64 48 | tr -dc 'A-Za-z0-9' | head -c 32)
echo "$user:$password" > "$tmp/passwords.txt"
sed -e "s|\"tls/localhost:7447\"|\"$endpoint\"|" \
    -e "s|\"set-by-make-certs\"|\"$password\"|" \
    "$here/zenoh/node.json5" > "$tmp/node.json5"
if ! grep -q "$password" "$tmp/node.json5" || ! grep -qF "\"$endpoint\"" "$tmp/node.json5"; then
  echo "make-certs: error: $here/zenoh/node.json5 lacks the placeholders to fill in" >&2
  exit 1
fi
chmod 644 "$tmp/ca.pem" "$tmp/router.pem" "$tmp/node.json5"

for f in ca.pem ca-key.pem router.pem router-key.pem passwords.txt node.json5; do
  mv -f "$tmp/$f" "$out/$f"
done
echo "make-certs: wrote $out (router certificate for $sans; nodes connect to $endpoint)"
