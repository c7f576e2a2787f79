# The builder of the wart lab's image: the Debian base, a C compiler, and a venv with
# every dependency of the project installed from the wheels in the build context.
#
# deploy/container/build makes it once per set of wheels (its tag is a hash of them,
# of this file and of the base), and the image (Containerfile) starts from it: a build
# after a change to the project's sources installs the project and compiles its
# kernels, not its 60 dependencies again. It is never shipped: the runtime
# (Containerfile.runtime) copies its venv out of it onto the base, and the image the
# project's files and install.

ARG BASE=localhost/wart-base:bookworm
FROM ${BASE}
# The compiler and Python's headers for the kernels' module, from Debian's packages.
RUN apt-get update -qq \
    && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
        gcc g++ libc6-dev libpython3.11-dev >/dev/null \
    && rm -rf /var/lib/apt/lists/*
# The wheels stay: the project's own install (editable) takes its build backend from them.
COPY wheels /opt/wheels
RUN python3 -m venv /opt/wart/.venv \
    && /opt/wart/.venv/bin/pip install -q --no-index --find-links /opt/wheels /opt/wheels/*.whl \
    && rm -rf /root/.cache
