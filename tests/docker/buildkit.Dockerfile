# BuildKit's daemon (buildkitd, buildctl) built from Debian's source of docker.io (its buildkit
# component) with Debian's Go and -dev packages, GOPATH-style as debian/rules lays it out: an
# image that stands in for moby/buildkit (which cannot be pulled here) as the image of a buildx
# docker-container builder (--driver-opt image=...). BASE_IMAGE: any Debian trixie image with
# apt and python3 (the tests use their ROS 2 base). See tests/buildkit.py.
ARG BASE_IMAGE
FROM ${BASE_IMAGE} AS build
# What buildkitd and buildctl import from /usr/share/gocode (go list -deps, dpkg -S).
RUN apt-get update && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends \
        ca-certificates golang-go patch xz-utils \
        golang-github-agext-levenshtein-dev golang-github-appc-cni-dev \
        golang-github-armon-circbuf-dev golang-github-aws-aws-sdk-go-v2-dev \
        golang-github-aws-smithy-go-dev golang-github-beorn7-perks-dev \
        golang-github-cenkalti-backoff-dev golang-github-cespare-xxhash-dev \
        golang-github-containerd-console-dev golang-github-containerd-containerd-dev \
        golang-github-containerd-continuity-dev golang-github-containerd-errdefs-dev \
        golang-github-containerd-fifo-dev golang-github-containerd-go-cni-dev \
        golang-github-containerd-go-runc-dev golang-github-containerd-log-dev \
        golang-github-containerd-platforms-dev golang-github-containerd-ttrpc-dev \
        golang-github-containerd-typeurl-dev golang-github-coreos-bbolt-dev \
        golang-github-coreos-go-systemd-dev golang-github-dimchansky-utfbom-dev \
        golang-github-distribution-reference-dev \
        golang-github-docker-docker-credential-helpers-dev \
        golang-github-docker-go-connections-dev golang-github-docker-go-events-dev \
        golang-github-docker-go-metrics-dev golang-github-docker-go-units-dev \
        golang-github-felixge-httpsnoop-dev golang-github-go-logr-logr-dev \
        golang-github-go-logr-stdr-dev golang-github-gofrs-flock-dev \
        golang-github-gogo-googleapis-dev golang-github-gogo-protobuf-dev \
        golang-github-golang-groupcache-dev golang-github-golang-jwt-jwt-dev \
        golang-github-golang-protobuf-1-5-dev golang-github-google-go-cmp-dev \
        golang-github-google-shlex-dev golang-github-google-uuid-dev \
        golang-github-grpc-ecosystem-grpc-gateway-dev golang-github-hashicorp-errwrap-dev \
        golang-github-hashicorp-go-immutable-radix-dev golang-github-hashicorp-go-multierror-dev \
        golang-github-hashicorp-golang-lru-dev golang-github-in-toto-in-toto-golang-dev \
        golang-github-klauspost-compress-dev golang-github-mitchellh-hashstructure-dev \
        golang-github-moby-docker-image-spec-dev golang-github-moby-locker-dev \
        golang-github-moby-patternmatcher-dev golang-github-moby-sys-dev \
        golang-github-morikuni-aec-dev golang-github-munnerz-goautoneg-dev \
        golang-github-opencontainers-go-digest-dev golang-github-opencontainers-image-spec-dev \
        golang-github-opencontainers-selinux-dev golang-github-opencontainers-specs-dev \
        golang-github-pelletier-go-toml-dev \
        golang-github-pkg-errors-dev golang-github-prometheus-client-golang-dev \
        golang-github-prometheus-client-model-dev golang-github-prometheus-common-dev \
        golang-github-prometheus-procfs-dev \
        golang-github-secure-systems-lab-go-securesystemslib-dev \
        golang-github-shibumi-go-pathspec-dev golang-github-sirupsen-logrus-dev \
        golang-github-tonistiigi-units-dev golang-github-vbatts-tar-split-dev \
        golang-github-vishvananda-netlink-dev golang-github-vishvananda-netns-dev \
        golang-golang-x-crypto-dev golang-golang-x-net-dev golang-golang-x-sync-dev \
        golang-golang-x-sys-dev golang-golang-x-text-dev golang-golang-x-time-dev \
        golang-google-genproto-dev golang-google-grpc-dev golang-google-protobuf-dev \
        golang-opentelemetry-contrib-dev golang-opentelemetry-otel-dev \
        golang-opentelemetry-proto-dev \
    && rm -rf /var/lib/apt/lists/*
ARG DEBIAN_POOL=http://deb.debian.org/debian/pool/main/d/docker.io
# the docker.io source version and its files' checksums (`<sha256>:<file> ...`), which the
# tests choose: tests/engines.py docker_io_source
ARG DOCKER_IO_VERSION
ARG DOCKER_IO_REVISION
ARG DOCKER_IO_SHA256
# orig: the engine (buildkit imports its pkg/archive and friends); orig-buildkit: BuildKit;
# debian: the patches Debian applies to BuildKit (no hcsshim, no jaeger, grpc-middleware v1).
WORKDIR /src
RUN test -n "$DOCKER_IO_VERSION" && test -n "$DOCKER_IO_REVISION" && test -n "$DOCKER_IO_SHA256" \
    && for entry in $DOCKER_IO_SHA256; do echo "${entry%%:*}  ${entry#*:}"; done > SHA256SUMS \
    && for name in orig orig-buildkit; do \
        python3 -c 'import sys, urllib.request; urllib.request.urlretrieve(sys.argv[1], sys.argv[2])' \
            "$DEBIAN_POOL/docker.io_${DOCKER_IO_VERSION}.$name.tar.xz" "docker.io_${DOCKER_IO_VERSION}.$name.tar.xz"; \
    done \
    && python3 -c 'import sys, urllib.request; urllib.request.urlretrieve(sys.argv[1], sys.argv[2])' \
        "$DEBIAN_POOL/docker.io_${DOCKER_IO_VERSION}-${DOCKER_IO_REVISION}.debian.tar.xz" \
        "docker.io_${DOCKER_IO_VERSION}-${DOCKER_IO_REVISION}.debian.tar.xz" \
    && sha256sum -c SHA256SUMS \
    && mkdir tree tree/buildkit \
    && tar -xJf docker.io_${DOCKER_IO_VERSION}.orig.tar.xz -C tree --strip-components=2 \
    && tar -xJf docker.io_${DOCKER_IO_VERSION}.orig-buildkit.tar.xz -C tree/buildkit --strip-components=2 \
    && tar -xJf docker.io_${DOCKER_IO_VERSION}-${DOCKER_IO_REVISION}.debian.tar.xz -C tree \
    && cd tree \
    && for patch in buildkit-remove-hcsshim buildkit-remove-jaeger grpc-middleware-v1; do \
        patch -p1 --quiet --forward < debian/patches/$patch.patch; \
    done \
    && mkdir -p /gopath/src/github.com/moby /gopath/src/github.com/docker \
    && mv buildkit /gopath/src/github.com/moby/buildkit \
    && mv engine /gopath/src/github.com/docker/docker \
    && rm -rf /src
ENV GOPATH=/gopath:/usr/share/gocode GO111MODULE=off GOPROXY=off CGO_ENABLED=0
WORKDIR /gopath/src/github.com/moby/buildkit
RUN ldflags="-s -w -X github.com/moby/buildkit/version.Version=v0.13-debian${DOCKER_IO_VERSION}-${DOCKER_IO_REVISION}" \
    && go build -trimpath -ldflags "$ldflags" -o /out/buildkitd ./cmd/buildkitd \
    && go build -trimpath -ldflags "$ldflags" -o /out/buildctl ./cmd/buildctl \
    && rm -rf /root/.cache/go-build

FROM ${BASE_IMAGE}
# runc: buildkitd's OCI worker runs each RUN step with it.
RUN apt-get update && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends \
        runc \
    && rm -rf /var/lib/apt/lists/*
COPY --from=build /out/buildkitd /out/buildctl /usr/bin/
VOLUME /var/lib/buildkit
ENTRYPOINT ["buildkitd"]
