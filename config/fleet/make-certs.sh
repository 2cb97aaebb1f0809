#!/bin/sh
# Certificates to try the fleet set-up (README, "A fleet"): a CA, and a certificate per
# NAME whose common name is NAME, the identity [zenoh.access] grants to. A site uses its
# own PKI instead. From any folder:
#
#     sh config/fleet/make-certs.sh DIR CA [NAME...]
#     sh config/fleet/make-certs.sh config/fleet/certs ca router shovel1 shovel2 control-room
#
# makes DIR/CA.pem (and CA.key) unless it exists, then DIR/NAME.pem and DIR/NAME.key signed
# by it, valid as a server for localhost and 127.0.0.1 (set SAN="DNS:host,IP:10.1.2.3" for
# a router elsewhere). Needs openssl.
set -eu
[ $# -ge 2 ] || { echo "usage: $0 DIR CA [NAME...]" >&2; exit 2; }
dir=$1 ca=$2
shift 2
san=${SAN:-DNS:localhost,IP:127.0.0.1}
days=${DAYS:-825}
mkdir -p "$dir"
cd "$dir"
umask 077
quiet() { "$@" 2>openssl.err || { cat openssl.err >&2; rm -f openssl.err; exit 1; }; rm -f openssl.err; }
if [ ! -f "$ca.pem" ]; then
    quiet openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes \
        -keyout "$ca.key" -out "$ca.pem" -days "$days" -subj "/CN=dcobserver fleet CA $ca"
fi
for name in "$@"; do
    quiet openssl req -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes \
        -keyout "$name.key" -out "$name.csr" -subj "/CN=$name"
    printf 'subjectAltName=%s\nextendedKeyUsage=serverAuth,clientAuth\n' "$san" >"$name.ext"
    quiet openssl x509 -req -in "$name.csr" -CA "$ca.pem" -CAkey "$ca.key" -CAcreateserial \
        -out "$name.pem" -days "$days" -extfile "$name.ext"
    rm -f "$name.csr" "$name.ext"
    chmod 644 "$name.pem"
done
chmod 644 "$ca.pem"
echo "$dir: $ca.pem and $*"
