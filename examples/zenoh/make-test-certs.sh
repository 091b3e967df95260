#!/bin/sh
# Generate a throw-away certificate authority and a server certificate for the
# streamid daemon's TLS listener (examples/zenoh/tls/*.json5), with openssl.
#
#   sh examples/zenoh/make-test-certs.sh [OUTDIR] [DAYS] [NAMES]
#
# OUTDIR (default examples/zenoh/certs, git-ignored) receives:
#   ca.pem       the CA certificate      -> clients' transport/link/tls/root_ca_certificate
#   daemon.pem   the daemon certificate  -> daemon's transport/link/tls/listen_certificate
#   daemon.key   its private key (0600)  -> daemon's transport/link/tls/listen_private_key
# The CA's private key is deleted once it has signed: nothing else can be signed with it.
# The daemon certificate is valid for NAMES (default IP:127.0.0.1,DNS:localhost: loopback; for a
# router another machine reaches, its address, e.g. IP:192.0.2.10 or DNS:router.example.org);
# for a real deployment use certificates from your own PKI naming the daemon's host.
# Never commit private keys.
set -eu
OUT=${1:-examples/zenoh/certs}
DAYS=${2:-30}
NAMES=${3:-IP:127.0.0.1,DNS:localhost}
umask 077
mkdir -p "$OUT"
TMP=$(mktemp -d)
trap 'rm -rf "$TMP"' EXIT INT TERM
openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes \
    -keyout "$TMP/ca.key" -out "$OUT/ca.pem" -days "$DAYS" \
    -subj "/CN=streamid test CA" \
    -addext "basicConstraints=critical,CA:TRUE" -addext "keyUsage=critical,keyCertSign,cRLSign" 2>/dev/null
openssl req -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes \
    -keyout "$OUT/daemon.key" -out "$TMP/daemon.csr" -subj "/CN=streamid-daemon" 2>/dev/null
printf '%s\n' "subjectAltName=$NAMES" "basicConstraints=critical,CA:FALSE" \
    "keyUsage=critical,digitalSignature" "extendedKeyUsage=serverAuth" > "$TMP/ext.cnf"
openssl x509 -req -in "$TMP/daemon.csr" -CA "$OUT/ca.pem" -CAkey "$TMP/ca.key" -CAcreateserial \
    -CAserial "$TMP/ca.srl" -out "$OUT/daemon.pem" -days "$DAYS" -extfile "$TMP/ext.cnf" 2>/dev/null
chmod 644 "$OUT/ca.pem" "$OUT/daemon.pem"
echo "wrote $OUT/ca.pem $OUT/daemon.pem $OUT/daemon.key"
