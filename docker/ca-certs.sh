# Sourced by every RUN that may reach HTTPS: trust EXTRA_CA_CERTS (a BuildKit secret, so the
# certificates never enter a layer) for apt, pip, git, curl and Python's ssl during this RUN.
# Files made here go to /run/docker-ros, a tmpfs mount of the same RUN, never into the layer.
secret=/run/secrets/EXTRA_CA_CERTS
tmp=/run/docker-ros
if [ -s "$secret" ]; then
    DOCKER_ROS_CA_FILE="$secret"
    if [ -d "$tmp" ] && [ -s /etc/ssl/certs/ca-certificates.crt ]; then
        cat /etc/ssl/certs/ca-certificates.crt "$secret" > "$tmp/ca.pem" && DOCKER_ROS_CA_FILE="$tmp/ca.pem"
    fi
    export DOCKER_ROS_CA_FILE SSL_CERT_FILE="$DOCKER_ROS_CA_FILE" PIP_CERT="$DOCKER_ROS_CA_FILE" \
        REQUESTS_CA_BUNDLE="$DOCKER_ROS_CA_FILE" CURL_CA_BUNDLE="$DOCKER_ROS_CA_FILE" \
        GIT_SSL_CAINFO="$DOCKER_ROS_CA_FILE"
    if [ -d "$tmp" ]; then
        printf 'Acquire::https::CaInfo "%s";\n' "$DOCKER_ROS_CA_FILE" > "$tmp/apt.conf"
        export APT_CONFIG="$tmp/apt.conf"
    fi
fi
