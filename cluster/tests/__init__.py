"""Unit tests of the cluster package that need no Ray: `python -m unittest discover -s cluster/tests -t .`
(or `python -m pytest cluster/tests`). The multi-node test is `cluster/test_local_cluster.sh`."""
