# One image for every AVS service (compose.yaml picks the service by its command), and the
# router image (target `router`): AVS's Python Zenoh router reading deploy/zenoh's configs.
#   DOCKER_BUILDKIT=1 docker build -t avs .                 # from python:3.11-slim
#   DOCKER_BUILDKIT=1 docker build --target router -t avs-router .
#   docker run avs python -m services.sim
# BASE: any Debian-family image with python3 (>= 3.11) and venv; without a registry,
# scripts/docker-setup makes one from Debian packages (mmdebstrap + docker import).
# Packages: from the wheelhouse deploy/wheels when it holds wheels (scripts/docker-setup fills
# it from this host's pip configuration; bind-mounted, never copied), else from the index, with
# pip's cache in a BuildKit cache mount and an optional CA bundle as the secret `ca`.
ARG BASE=python:3.11-slim

FROM ${BASE} AS deps
RUN python3 -m venv /opt/avs
WORKDIR /src
COPY pyproject.toml constraints.txt ./
# the dependencies, from pyproject alone: a change of the sources reuses this stage
RUN --mount=type=cache,target=/root/.cache/pip,sharing=locked \
    --mount=type=bind,source=deploy/wheels,target=/wheels \
    --mount=type=secret,id=ca \
    set -e; \
    if [ -f /run/secrets/ca ]; then export PIP_CERT=/run/secrets/ca; fi; \
    if ls /wheels/*.whl >/dev/null 2>&1; then set -- --no-index --find-links /wheels; fi; \
    /opt/avs/bin/python -c 'import tomllib; print("\n".join( \
      tomllib.load(open("pyproject.toml", "rb"))["project"]["dependencies"]))' > deps.txt; \
    /opt/avs/bin/pip install --disable-pip-version-check -q "$@" -c constraints.txt -r deps.txt

# AVS itself, as a wheel the runtime stage installs over the dependencies' layer
FROM deps AS wheel
COPY README.md ./
COPY schemas ./schemas
COPY services ./services
COPY experiments ./experiments
COPY avs ./avs
RUN --mount=type=cache,target=/root/.cache/pip,sharing=locked \
    --mount=type=bind,source=deploy/wheels,target=/wheels \
    --mount=type=secret,id=ca \
    set -e; \
    if [ -f /run/secrets/ca ]; then export PIP_CERT=/run/secrets/ca; fi; \
    if ls /wheels/*.whl >/dev/null 2>&1; then set -- --no-index --find-links /wheels; fi; \
    /opt/avs/bin/pip wheel --disable-pip-version-check -q "$@" --no-deps -w /dist .

FROM ${BASE} AS runtime
# Open3D needs libusb, libGL and libgomp; MuJoCo renders headless through EGL on Mesa. A base
# that has them already (scripts/docker-setup's) needs no package index here.
RUN set -e; missing=""; \
    for p in libusb-1.0-0 libgl1 libgomp1 libegl1 libegl-mesa0 libgl1-mesa-dri; do \
      dpkg -s "$p" >/dev/null 2>&1 || missing="$missing $p"; \
    done; \
    if [ -n "$missing" ]; then \
      apt-get update && apt-get install -y --no-install-recommends $missing \
      && rm -rf /var/lib/apt/lists/*; \
    fi; \
    useradd --create-home --uid 10001 avs \
 && install -d -o avs -g avs /var/lib/avs/scene_memory \
 && install -d -o avs -g avs /home/avs/.cache
# the dependencies' layer (gigabytes) apart from AVS's own: a change of the sources rebuilds a
# small wheel and a small layer
COPY --from=deps /opt/avs /opt/avs
RUN --mount=type=bind,from=wheel,source=/dist,target=/dist \
    /opt/avs/bin/pip install --disable-pip-version-check -q --no-deps --no-index /dist/*.whl
LABEL avs.image=1
ENV PATH=/opt/avs/bin:$PATH \
    MUJOCO_GL=egl \
    PYTHONUNBUFFERED=1

# what `avs up` runs in-process, as a container: the same -c/-l arguments as eclipse/zenoh's
# zenohd, the same config files (root, like zenohd's image: credentials.txt is the owner's only)
FROM runtime AS router
ENTRYPOINT ["python", "-m", "avs.router"]
CMD ["-c", "/etc/avs/router-tcp.json5"]

FROM runtime AS avs
USER avs
WORKDIR /home/avs
# the services' compiled kernels, into the image's numba cache (~/.cache/avs/numba): a container
# starts in seconds instead of compiling them at every start (a minute with six at once on two
# cores); a machine with another CPU recompiles what does not fit it, as numba does
RUN avs warm-up
CMD ["avs", "--help"]
