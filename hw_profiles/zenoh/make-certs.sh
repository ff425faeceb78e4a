#!/usr/bin/env sh
# Make a private CA and the TLS certificates of a legws deployment (zenoh mutual TLS).
#
#   hw_profiles/zenoh/make-certs.sh OUT_DIR [DAEMON_HOST ...]
#
# Writes into OUT_DIR (created if missing; existing files are never overwritten):
#   ca.pem                            the CA certificate: every party gets a copy
#   ca-key.pem                        the CA's private key: keep it offline, it signs new certs
#   daemon.pem / daemon-key.pem       CN legws-daemon; SAN localhost, 127.0.0.1 and each
#                                     DAEMON_HOST (a DNS name or an IP address) clients dial
#   operator.pem / operator-key.pem   CN legws-operator: the one identity that may steer
#   observer.pem / observer-key.pem   CN legws-observer: status and events only
#   bridge.pem / bridge-key.pem       CN legws-bridge: the robot-side bridge (sawyer profile)
#
# Keys are EC P-256 in PKCS#8, mode 0600; certificates are valid for DAYS (default 825) days.
# Copy to each machine only its own key and certificate plus ca.pem. Needs openssl (1.1.1+).
set -eu

if [ "$#" -lt 1 ] || [ "$1" = "-h" ] || [ "$1" = "--help" ]; then
    echo "usage: $0 OUT_DIR [DAEMON_HOST ...]" >&2
    exit 2
fi
command -v openssl >/dev/null 2>&1 || { echo "$0: openssl not found" >&2; exit 2; }

out=$1
shift
days=${DAYS:-825}
mkdir -p "$out"
umask 077

for name in ca daemon operator observer bridge; do
    if [ -e "$out/$name.pem" ] || [ -e "$out/$name-key.pem" ]; then
        echo "$0: $out/$name.pem or $out/$name-key.pem exists; not overwriting" >&2
        exit 1
    fi
done

tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT INT TERM

key() {  # key FILE: a fresh EC P-256 private key (PKCS#8 PEM)
    openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$1" 2>/dev/null
}

key "$out/ca-key.pem"
openssl req -x509 -new -key "$out/ca-key.pem" -sha256 -days "$days" \
    -subj "/O=legws/CN=legws-ca" \
    -addext "basicConstraints=critical,CA:TRUE,pathlen:0" \
    -addext "keyUsage=critical,keyCertSign,cRLSign" \
    -out "$out/ca.pem"

san="DNS:localhost,IP:127.0.0.1"
for host in "$@"; do
    case $host in
        *[!0-9.]*) case $host in *:*) san="$san,IP:$host" ;; *) san="$san,DNS:$host" ;; esac ;;
        *) san="$san,IP:$host" ;;
    esac
done

sign() {  # sign NAME COMMON_NAME SUBJECT_ALT_NAMES
    key "$out/$1-key.pem"
    openssl req -new -key "$out/$1-key.pem" -subj "/O=legws/CN=$2" -out "$tmp/$1.csr"
    cat >"$tmp/$1.ext" <<EXT
basicConstraints = critical, CA:FALSE
keyUsage = critical, digitalSignature, keyEncipherment
extendedKeyUsage = serverAuth, clientAuth
subjectAltName = $3
EXT
    openssl x509 -req -in "$tmp/$1.csr" -CA "$out/ca.pem" -CAkey "$out/ca-key.pem" \
        -CAcreateserial -CAserial "$tmp/ca.srl" -sha256 -days "$days" \
        -extfile "$tmp/$1.ext" -out "$out/$1.pem" 2>/dev/null
}

sign daemon legws-daemon "$san"
sign operator legws-operator "DNS:legws-operator"
sign observer legws-observer "DNS:legws-observer"
sign bridge legws-bridge "DNS:localhost,IP:127.0.0.1,DNS:legws-bridge"
chmod 600 "$out"/*-key.pem
chmod 644 "$out"/ca.pem "$out"/daemon.pem "$out"/operator.pem "$out"/observer.pem "$out"/bridge.pem
echo "$0: wrote ca, daemon, operator, observer and bridge certificates to $out" >&2
