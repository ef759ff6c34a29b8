#!/usr/bin/env bash
# Make a small private PKI for the mocap Zenoh network with the openssl command line:
#   OUT_DIR/ca.pem, ca.key            the certificate authority (keep ca.key offline)
#   OUT_DIR/router.pem, router.key    the router's certificate (names: localhost, 127.0.0.1, and ADDRESS...)
#   OUT_DIR/NAME.pem, NAME.key        one client certificate per NAME, common name (CN) = NAME
#
# usage: deploy/make-certs.sh [-c "tracker game cloth"] [-d DAYS] OUT_DIR [ADDRESS ...]
#   ADDRESS   an IP address or DNS name the clients use in --connect tls/ADDRESS:7447
#   -c NAMES  client certificates to make (default: tracker game cloth)
#   -d DAYS   validity (default 365)
# Run it again with the same OUT_DIR to add clients: an existing CA (and router certificate) is reused.
set -euo pipefail

clients="tracker game cloth"
days=365
while getopts "c:d:h" opt; do
  case "$opt" in
    c) clients="$OPTARG" ;;
    d) days="$OPTARG" ;;
    *) sed -n '2,12p' "$0"; exit 2 ;;
  esac
done
shift $((OPTIND - 1))
[ $# -ge 1 ] || { sed -n '2,12p' "$0"; exit 2; }
out="$1"; shift

san="DNS:localhost,IP:127.0.0.1"
for a in "$@"; do
  if [[ "$a" =~ ^[0-9.]+$ || "$a" == *:* ]]; then san="$san,IP:$a"; else san="$san,DNS:$a"; fi
done

mkdir -p "$out"
umask 077
cd "$out"

newkey() { openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$1" 2>/dev/null; }

if [ ! -f ca.pem ]; then
  newkey ca.key
  openssl req -x509 -new -key ca.key -sha256 -days "$days" -subj "/CN=mocap-ca" \
    -addext "basicConstraints=critical,CA:TRUE" -addext "keyUsage=critical,keyCertSign,cRLSign" \
    -out ca.pem
  echo "made CA: $out/ca.pem"
fi

# sign NAME "extensions": NAME.key + NAME.pem with CN=NAME, signed by the CA
sign() {
  local name="$1" ext="$2"
  newkey "$name.key"
  openssl req -new -key "$name.key" -subj "/CN=$name" -out "$name.csr"
  printf 'basicConstraints=CA:FALSE\nkeyUsage=critical,digitalSignature\n%b\n' "$ext" > "$name.ext"
  openssl x509 -req -in "$name.csr" -CA ca.pem -CAkey ca.key -CAcreateserial -sha256 -days "$days" \
    -extfile "$name.ext" -out "$name.pem" 2>/dev/null
  rm -f "$name.csr" "$name.ext"
  echo "made certificate $out/$name.pem (CN=$name)"
}

if [ ! -f router.pem ] || [ $# -gt 0 ]; then
  sign router "extendedKeyUsage=serverAuth,clientAuth\nsubjectAltName=$san"
fi
for c in $clients; do
  sign "$c" "extendedKeyUsage=clientAuth\nsubjectAltName=DNS:$c"
done
chmod 644 ./*.pem

