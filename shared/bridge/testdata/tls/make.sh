#!/usr/bin/env bash
# Test-only certificates for the TLS link tests (never for a real run: the keys are
# public). Regenerate with `bash make.sh` (openssl 3): a CA, a certificate for each
# of the two test hosts signed by it (both name localhost and 127.0.0.1, and may serve
# and connect), and a stranger's certificate from another CA, which must be refused.
set -euo pipefail
cd "$(dirname "$0")"
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
days=36500
key() { openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$1" 2>/dev/null; }
ca() { # name subject
  key "$tmp/$1.key"
  openssl req -x509 -new -key "$tmp/$1.key" -subj "/CN=$2" -days $days -sha256 \
    -addext "basicConstraints=critical,CA:TRUE" -addext "keyUsage=critical,keyCertSign,cRLSign" -out "$1.pem"
}
host() { # name ca
  key "$1.key"
  openssl req -new -key "$1.key" -subj "/CN=$1" -out "$tmp/$1.csr"
  printf '%s\n' "basicConstraints=critical,CA:FALSE" "keyUsage=critical,digitalSignature" \
    "extendedKeyUsage=serverAuth,clientAuth" "subjectAltName=DNS:localhost,IP:127.0.0.1" > "$tmp/$1.ext"
  openssl x509 -req -in "$tmp/$1.csr" -CA "$2.pem" -CAkey "$tmp/$2.key" -CAcreateserial -days $days -sha256 \
    -extfile "$tmp/$1.ext" -out "$1.pem" 2>/dev/null
}
ca ca "pednav test CA"
ca stranger-ca "another CA"
host learner-host ca
host actor-host ca
host stranger stranger-ca
rm -f stranger-ca.pem ./*.srl
