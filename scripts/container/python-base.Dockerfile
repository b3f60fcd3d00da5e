# Local stand-in for the official python:3.11-slim-bookworm image, for machines without a
# registry: Debian's own Python 3.11 on a debootstrap minbase image (scripts/container-smoke.sh
# builds localhost/debian:bookworm-minbase first). Same entry points as the official image:
# `python3` with the venv module.
FROM localhost/debian:bookworm-minbase

ENV LANG=C.UTF-8

RUN apt-get update \
    && apt-get install -y --no-install-recommends python3=3.11.* python3-venv=3.11.* ca-certificates=* \
    && apt-get clean \
    && rm -rf /var/lib/apt/lists/*

CMD ["python3"]
