"""Measuring tools used only by scripts/ (and their tests): the soak and its network
namespaces, the flood of frames, the speed report, the rollout floor, the argparse scripts'
option types. They import the project's packages; nothing in the project imports them."""
