#!/usr/bin/env bash
# A test SROS2 keystore, made with openssl alone, laid out as `ros2 security create_keystore`
# and `ros2 security create_enclave` lay theirs out:
#   KEYSTORE/public/{ca,identity_ca,permissions_ca}.cert.pem    the CA (one, in both roles)
#   KEYSTORE/private/{ca,identity_ca,permissions_ca}.key.pem
#   KEYSTORE/enclaves/governance.{xml,p7s}                       the domain's rules, signed
#   KEYSTORE/enclaves/ENCLAVE/{cert,key}.pem                     the enclave's identity (CN=ENCLAVE)
#   KEYSTORE/enclaves/ENCLAVE/permissions.{xml,p7s}              what it may publish and read
#   KEYSTORE/enclaves/ENCLAVE/{governance.p7s,identity_ca.cert.pem,permissions_ca.cert.pem}
# Governance: no unauthenticated participant joins; discovery, liveliness and every RTPS
# message are encrypted (rtps_protection_kind ENCRYPT: whole messages, so every sample too);
# every topic is access-controlled. Topic metadata and data are not encrypted a second time
# per submessage: RustDDS 0.15 fails to decode protected DATA_FRAG submessages (large samples:
# maps, images), measured here. Permissions: each enclave may publish and subscribe every topic
# on every domain (a test keystore, not a policy).
#
# Use: scripts/make_test_keystore.sh KEYSTORE ENCLAVE [ENCLAVE ...]   (e.g. /angle_i2p /player)
# An existing keystore keeps its CA and gains the enclaves named.
set -euo pipefail
if [ $# -lt 2 ]; then
  echo "usage: $0 KEYSTORE ENCLAVE [ENCLAVE ...]" >&2
  exit 2
fi
keystore=$1
shift
mkdir -p "$keystore/public" "$keystore/private" "$keystore/enclaves"
cd "$keystore"

ec_key=(-newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes)
sign() { # sign IN OUT: S/MIME, signed by the permissions CA, as SROS2 signs its documents
  openssl smime -sign -text -in "$1" -out "$2" -signer public/permissions_ca.cert.pem \
    -inkey private/permissions_ca.key.pem
}

if [ ! -f private/ca.key.pem ]; then
  openssl req -x509 "${ec_key[@]}" -keyout private/ca.key.pem -out public/ca.cert.pem -days 3650 \
    -sha256 -subj "/CN=angle_i2p test keystore CA" 2>/dev/null
  for role in identity_ca permissions_ca; do
    cp public/ca.cert.pem "public/$role.cert.pem"
    cp private/ca.key.pem "private/$role.key.pem"
  done
  cat > enclaves/governance.xml <<'XML'
<?xml version="1.0" encoding="UTF-8"?>
<dds xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance"
     xsi:noNamespaceSchemaLocation="http://www.omg.org/spec/DDS-SECURITY/20170901/omg_shared_ca_governance.xsd">
  <domain_access_rules>
    <domain_rule>
      <domains><id_range><min>0</min><max>232</max></id_range></domains>
      <allow_unauthenticated_participants>false</allow_unauthenticated_participants>
      <enable_join_access_control>true</enable_join_access_control>
      <discovery_protection_kind>ENCRYPT</discovery_protection_kind>
      <liveliness_protection_kind>ENCRYPT</liveliness_protection_kind>
      <rtps_protection_kind>ENCRYPT</rtps_protection_kind>
      <topic_access_rules>
        <topic_rule>
          <topic_expression>*</topic_expression>
          <enable_discovery_protection>true</enable_discovery_protection>
          <enable_liveliness_protection>true</enable_liveliness_protection>
          <enable_read_access_control>true</enable_read_access_control>
          <enable_write_access_control>true</enable_write_access_control>
          <metadata_protection_kind>NONE</metadata_protection_kind>
          <data_protection_kind>NONE</data_protection_kind>
        </topic_rule>
      </topic_access_rules>
    </domain_rule>
  </domain_access_rules>
</dds>
XML
  sign enclaves/governance.xml enclaves/governance.p7s
fi

serial=$(date +%s)
not_before=$(date -u +%Y-%m-%dT%H:%M:%S)
not_after=$(date -u -d '+10 years' +%Y-%m-%dT%H:%M:%S)
for enclave in "$@"; do
  case $enclave in
    /*) ;;
    *) echo "enclave $enclave: must be an absolute name (/angle_i2p)" >&2; exit 2 ;;
  esac
  dir="enclaves$enclave"
  mkdir -p "$dir"
  # -subj separates attributes with '/': the enclave's own slashes are escaped.
  openssl req "${ec_key[@]}" -keyout "$dir/key.pem" -out "$dir/request.pem" -sha256 \
    -subj "/CN=${enclave//\//\\/}" 2>/dev/null
  serial=$((serial + 1))
  openssl x509 -req -in "$dir/request.pem" -CA public/identity_ca.cert.pem -CAkey private/identity_ca.key.pem \
    -out "$dir/cert.pem" -days 3650 -sha256 -set_serial "$serial" 2>/dev/null
  rm "$dir/request.pem"
  cat > "$dir/permissions.xml" <<XML
<?xml version="1.0" encoding="UTF-8"?>
<dds xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance"
     xsi:noNamespaceSchemaLocation="http://www.omg.org/spec/DDS-Security/20170901/omg_shared_ca_permissions.xsd">
  <permissions>
    <grant name="$enclave">
      <subject_name>CN=$enclave</subject_name>
      <validity><not_before>$not_before</not_before><not_after>$not_after</not_after></validity>
      <allow_rule>
        <domains><id_range><min>0</min><max>232</max></id_range></domains>
        <publish><topics><topic>*</topic></topics></publish>
        <subscribe><topics><topic>*</topic></topics></subscribe>
      </allow_rule>
      <default>DENY</default>
    </grant>
  </permissions>
</dds>
XML
  sign "$dir/permissions.xml" "$dir/permissions.p7s"
  cp enclaves/governance.p7s public/identity_ca.cert.pem public/permissions_ca.cert.pem "$dir/"
done
