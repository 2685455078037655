# Engine image: runs the paper's comparison. The service image (API + worker) comes with issue 4.
FROM python:3.11-slim
RUN useradd --create-home --uid 10001 spacearm
WORKDIR /app
COPY pyproject.toml README.md ./
COPY engine ./engine
COPY service ./service
RUN pip install --no-cache-dir .
USER spacearm
CMD ["python", "-m", "engine.demo"]
