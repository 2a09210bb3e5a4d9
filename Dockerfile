# One image for the fusion server and simulated agents (docker-compose.yml runs both).
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1
WORKDIR /app
COPY pyproject.toml README.md ./
COPY protocol ./protocol
COPY agent ./agent
COPY calibration ./calibration
COPY server ./server
COPY skelfuse ./skelfuse
RUN pip install --no-cache-dir '.[server]'

RUN useradd --create-home --uid 10001 skelfuse && mkdir /data && chown skelfuse /data
USER skelfuse
VOLUME ["/data"]
EXPOSE 8000 5555
CMD ["skelfuse", "server", "--http", "0.0.0.0:8000", "--zmq", "tcp://*:5555", "--data", "/data"]
