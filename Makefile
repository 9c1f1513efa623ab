.PHONY: demo test bootstrap

bootstrap:
	scripts/bootstrap.sh

demo: bootstrap
	.venv/bin/activetouch demo

test:
	scripts/test.sh
