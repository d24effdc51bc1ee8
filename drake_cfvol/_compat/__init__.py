"""The package's old module names (before the subpackages), each the new
module under its old name: ``import drake_cfvol.certify`` gives
:mod:`drake_cfvol.algorithm.certify` itself. This folder is on
``drake_cfvol.__path__``; nothing new goes here."""
