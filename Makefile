# Two entry points a fresh machine needs: `make demo` and `make test`.
# Both create .venv when missing and (re)install when pyproject.toml changed;
# `make docs` does the same with the docs extra and builds the site into site/.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
DOCS_STAMP := $(VENV)/.installed-docs
DEMO   := demo-out

.PHONY: demo test test-pythons bench clean golden browser-deps docs

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test]'
	touch $(STAMP)

$(DOCS_STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[docs]'
	touch $(DOCS_STAMP)

demo: $(STAMP)
	bash scripts/demo.sh $(VENV)/bin $(DEMO)

# -n auto: one pytest worker per core; --dist loadfile keeps a file's tests (and its module
# fixtures, which render once per worker that needs them) on one worker.
test: $(STAMP) browser-deps
	$(PY) -m pytest -q -n auto --dist loadfile

# The suite (less the slow and browser tests) under Python 3.10 and 3.13: scripts/test-pythons.sh.
test-pythons:
	bash scripts/test-pythons.sh

# Headless Chromium for tests/results/test_browser.py (Debian's chromium + chromium-driver, ~90 s
# to install). Never fails the build: where it cannot be installed (no root, no apt-get,
# no network) the browser tests skip and say why.
browser-deps:
	@if command -v chromium >/dev/null 2>&1 && command -v chromedriver >/dev/null 2>&1; then :; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	  echo "installing chromium and chromium-driver for the browser tests ..."; \
	  ( export DEBIAN_FRONTEND=noninteractive; timeout 900 apt-get update -qq && \
	    timeout 900 apt-get install -y -qq chromium chromium-driver >/dev/null ) \
	  || echo "chromium install failed; browser tests will be skipped"; \
	else echo "chromium is not installed and cannot be installed here (needs root and apt-get); browser tests will be skipped"; fi

bench: $(STAMP)
	$(PY) -m bench

# The documentation site (mkdocs-material; mkdocs.yml), warnings as errors: a dead link, a page
# missing from the nav or a docstring the API page cannot read fails the build. Output: site/.
docs: $(DOCS_STAMP)
	$(PY) -m mkdocs build --strict

golden: $(STAMP)
	$(PY) -m tests.golden.regenerate

clean:
	rm -rf $(VENV) .venv-3.* $(DEMO) site
