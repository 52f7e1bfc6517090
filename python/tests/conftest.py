"""The package's own tests use its pytest plugin's fixtures (``ftafm_daemon``,
``ftafm_instrument``): a real daemon (``$FTAFM_BIN``) on 127.0.0.1:0."""
