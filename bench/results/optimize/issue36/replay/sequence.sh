cd /work/main
export PYTHONPATH=/work/main/python
B=${B:-/tmp/dev}  # (a build folder: cmake -S . -B /tmp/dev ...)
O=${O:-/tmp/opt/replay}  # (the results folder)
for c in smoke cf cloud; do
 for F in "" "--freeze"; do
  /usr/bin/time -f "%e s gridvolume $c $F" python3 bench/optimize.py --target /tmp/opt/$c.vol --plugin gridvolume --reference /tmp/opt/$c.vol --ref-spp 256 --timing-rounds 2 --build $B --out $O $F > $O.$c.grid$F.log 2>&1
  /usr/bin/time -f "%e s prbvolpath nanovdb $c $F" python3 bench/optimize.py --target /tmp/opt/$c.nvdb --plugin nanovdbvolume --reference /tmp/opt/$c.vol --ref-spp 256 --filter stochastic_trilinear --timing-rounds 2 --build $B --out $O $F > $O.$c.nvdb$F.log 2>&1
  /usr/bin/time -f "%e s prbvolpathlocal $c $F" python3 bench/optimize.py --target /tmp/opt/$c.nvdb --plugin nanovdbvolume --reference /tmp/opt/$c.vol --ref-spp 256 --filter stochastic_trilinear --integrator prbvolpathlocal --timing-rounds 2 --build $B --out $O $F > $O.$c.local$F.log 2>&1
 done
done
python3 bench/optimize.py --compare $O
python3 /tmp/opt/summ.py $O
echo ALLDONE
