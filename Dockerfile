# One image for the fusion server and simulated agents (docker-compose.yml runs both).
# The first stage builds the wheel; the image installs that wheel with the server extras, so it
# holds exactly what `pip install 'skelfuse[server]'` installs, and no list of folders to keep.
# CI does the same steps without Docker (scripts/smoke_wheel.sh, run by .ci/run).
FROM python:3.11-slim AS wheel
WORKDIR /src
COPY . .
RUN pip wheel --no-cache-dir --no-deps --wheel-dir /wheels .

FROM python:3.11-slim
ENV PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1
# open3d (ICP calibration) links these and does not import without them; the slim image lacks
# them (scripts/venv.sh names the same list for a bare machine).
RUN apt-get update \
    && apt-get install -y --no-install-recommends libusb-1.0-0 libgl1 libegl1 libx11-6 libudev1 \
    && rm -rf /var/lib/apt/lists/*
COPY --from=wheel /wheels /wheels
RUN pip install --no-cache-dir "skelfuse[server] @ file://$(echo /wheels/skelfuse-*.whl)" \
    && rm -rf /wheels

# The fusion kernels (numba) compiled once here, into a cache the server reads at every start
# (~0.5 s instead of ~25 s); on a CPU other than the build machine's numba compiles again and
# keeps that in the same folder, which is the server user's for that reason.
ENV NUMBA_CACHE_DIR=/var/cache/skelfuse-numba
RUN useradd --create-home --uid 10001 skelfuse && mkdir /data && chown skelfuse /data \
    && python -c "from skelfuse.fusion.engine import warm_up; warm_up()" \
    && chown -R skelfuse "$NUMBA_CACHE_DIR"
USER skelfuse
WORKDIR /home/skelfuse
VOLUME ["/data"]
EXPOSE 8000 5555
CMD ["skelfuse", "server", "--http", "0.0.0.0:8000", "--zmq", "tcp://*:5555", "--data", "/data"]
