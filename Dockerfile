# One image for every AVS service; compose.yaml picks the service by its command.
# Build: docker build -t avs .   Run one service: docker run avs python -m services.sim

FROM python:3.11-slim AS build
RUN python -m venv /opt/avs
WORKDIR /src
COPY pyproject.toml README.md constraints.txt ./
COPY schemas ./schemas
COPY services ./services
COPY avs ./avs
RUN /opt/avs/bin/pip install --no-cache-dir -c constraints.txt .

FROM python:3.11-slim
# Open3D needs libusb, libGL and libgomp; MuJoCo renders headless through EGL on Mesa.
RUN apt-get update \
 && apt-get install -y --no-install-recommends \
      libusb-1.0-0 libgl1 libgomp1 libegl1 libegl-mesa0 libgl1-mesa-dri \
 && rm -rf /var/lib/apt/lists/* \
 && useradd --create-home --uid 10001 avs \
 && install -d -o avs -g avs /var/lib/avs/scene_memory
COPY --from=build /opt/avs /opt/avs
ENV PATH=/opt/avs/bin:$PATH \
    MUJOCO_GL=egl \
    PYTHONUNBUFFERED=1
USER avs
WORKDIR /home/avs
CMD ["avs", "--help"]
