"""Judging results: SNR and PSNR against a truth, held-out error of a store from the data alone,
and the speed-against-accuracy benchmark.

``judge`` may import every layer below it (core, capture, solve, stages, synthetic), never
``share``, ``archive`` or the CLI.
"""
