# The runtime (Containerfile.runtime) and a C compiler with Python's headers: where the
# image's build compiles the simulator's kernels ahead of time when no module compiled
# from the same kernel sources on this CPU was at hand (deploy/container/build makes it
# only then, once per runtime). It is never shipped: the image is the runtime plus the
# project's layer.

ARG RUNTIME=localhost/wart-runtime:latest
FROM ${RUNTIME}
RUN apt-get update -qq \
    && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
        gcc g++ libc6-dev libpython3.11-dev >/dev/null \
    && rm -rf /var/lib/apt/lists/*
