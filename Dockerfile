# The demo of README's first command in a container:
#   docker build -t immukf-sitl . && docker run --rm immukf-sitl
# flies scenarios/q_gyro_zeroed.yaml through sim -> fault proxy -> estimator on loopback inside
# the container and prints the summary. Keep the outputs with a volume:
#   docker run --rm -v "$PWD/out:/app/out" immukf-sitl
# Another scenario or options: docker run --rm immukf-sitl immukf-sitl run scenarios/fault_free.yaml --json
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    MPLBACKEND=Agg

WORKDIR /app

# What `pip install .` needs (the packages immukf_sitl and sim, with the aircraft files as
# package data), then the scenarios the demo flies.
COPY pyproject.toml README.md ./
COPY immukf_sitl/ immukf_sitl/
COPY sim/ sim/
RUN pip install . && immukf-sitl --help > /dev/null
COPY scenarios/ scenarios/

CMD ["immukf-sitl", "run", "scenarios/q_gyro_zeroed.yaml"]
