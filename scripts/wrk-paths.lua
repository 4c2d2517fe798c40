-- wrk script: GET a random line's path with its Range header, from a file of
-- `PATH RANGE` lines (written by `cargo run --release -p streamer --example attack --
-- --paths DB N`). Usage: wrk ... -s scripts/wrk-paths.lua URL -- paths.txt
local paths, ranges = {}, {}

function init(args)
  for line in io.lines(args[1]) do
    local p, r = line:match("^(%S+) (%S+)$")
    if p then
      paths[#paths + 1] = p
      ranges[#ranges + 1] = r
    end
  end
  math.randomseed(os.time() + #paths)
end

function request()
  local i = math.random(#paths)
  return wrk.format("GET", paths[i], { ["Range"] = ranges[i] })
end
