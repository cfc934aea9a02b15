#include "preprocess/xyz_reader.hpp"

#include <algorithm>
#include <cmath>
#include <memory>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "preprocess/parallel.hpp"
#include "preprocess/reader_toolkit.hpp"

namespace pointillist::preprocess {
namespace {

using detail::failAtLine;

// Lines looked at before the 6- and 9-column layouts are decided.
constexpr std::size_t kSniffLines = 256;

enum class Triple { Normal, Color };

struct Layout {
  std::size_t columns = 3;
  int normalAt = -1;        // first column of nx ny nz, or -1
  int colorAt = -1;         // first column of r g b, or -1
  bool unitColors = false;  // colours stored as 0..1 floats
};

struct Row {
  std::uint64_t line;
  std::vector<double> values;
};

bool looksLikeNormal(const double* v) {
  const double length = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
  return std::abs(length - 1.0) < 0.05 || length == 0.0;
}

bool looksLikeColor(const double* v) {
  return std::all_of(v, v + 3, [](double c) { return c >= 0.0 && c <= 255.0; });
}

class XyzParser {
 public:
  XyzParser(const std::filesystem::path& file, const ReadOptions& options)
      : file_(file),
        reader_(file),
        builder_(file, options),
        streaming_(static_cast<bool>(options.sink)) {}

  PointCloud run() {
    std::vector<Row> sniffed;
    Row row;
    while (sniffed.size() < kSniffLines && nextRow(row)) sniffed.push_back(row);
    // The array is sized after the first block of lines (readRestInBlocks):
    // the first few lines' length guessed it a few percent short, and the
    // array then moved near the end.
    if (sniffed.empty()) {
      if (countLine_ > 0) {
        failAtLine(file_, countLine_,
                   "PTS header announces " + std::to_string(expectedCount_) +
                       " points but the file has none");
      }
      detail::failFile(file_, "contains no points");
    }
    decideLayout(sniffed);
    for (const Row& r : sniffed) addRow(r);
    readRestInBlocks();
    if (countLine_ > 0 && rows_ != expectedCount_) {
      failAtLine(file_, reader_.lineNumber(),
                 "PTS header (line " + std::to_string(countLine_) + ") announces " +
                     std::to_string(expectedCount_) + " points but the file has " +
                     std::to_string(rows_));
    }
    builder_.progress(reader_.size(), reader_.size());
    return builder_.finish(layout_.normalAt >= 0, layout_.colorAt >= 0, false);
  }

 private:
  // Next data line as numbers; false at end of file.
  bool nextRow(Row& row) {
    std::string_view line;
    for (;;) {
      if (!reader_.readLine(line)) return false;
      const std::size_t hash = line.find('#');
      if (hash != std::string_view::npos) line = line.substr(0, hash);
      detail::splitFields(line, fields_);
      if (fields_.empty()) continue;
      const std::uint64_t at = reader_.lineNumber();
      if (columns_ == 0 && fields_.size() == 1 && countLine_ == 0) {
        // A PTS point count before the first point.
        if (!detail::parseUnsigned(fields_[0], expectedCount_)) {
          failAtLine(file_, at,
                     "expected a point count or x y z, got '" + std::string(fields_[0]) + "'");
        }
        countLine_ = at;
        continue;
      }
      if (columns_ == 0) {
        columns_ = fields_.size();
        firstLine_ = at;
        if (columns_ != 3 && columns_ != 4 && columns_ != 6 && columns_ != 7 && columns_ != 9) {
          failAtLine(file_, at,
                     std::to_string(columns_) +
                         " values per line; expected 3 (x y z), 4 (x y z i), 6 (x y z nx ny nz "
                         "or x y z r g b), 7 (x y z i r g b) or 9");
        }
      } else if (fields_.size() != columns_) {
        failAtLine(file_, at,
                   std::to_string(fields_.size()) + " values, but line " +
                       std::to_string(firstLine_) + " has " + std::to_string(columns_) +
                       " (the layout is fixed by the first line)");
      }
      row.line = at;
      row.values.resize(columns_);
      for (std::size_t i = 0; i < columns_; ++i) {
        if (!detail::parseDouble(fields_[i], row.values[i])) {
          failAtLine(file_, at, "not a number: '" + std::string(fields_[i]) + "'");
        }
      }
      return true;
    }
  }

  // Which of the 3-value groups at `at` are normals or colours, over all sniffed rows.
  bool allRows(const std::vector<Row>& rows, std::size_t at, Triple kind) const {
    return std::all_of(rows.begin(), rows.end(), [&](const Row& r) {
      return kind == Triple::Normal ? looksLikeNormal(&r.values[at])
                                    : looksLikeColor(&r.values[at]);
    });
  }

  void decideLayout(const std::vector<Row>& rows) {
    layout_.columns = columns_;
    const auto fail = [&] {
      failAtLine(file_, rows.front().line,
                 "cannot tell normals from colours in the " + std::to_string(columns_) +
                     "-column layout (normals must be unit vectors, colours 0..255 or 0..1)");
    };
    switch (columns_) {
      case 6:
        if (allRows(rows, 3, Triple::Normal)) {
          layout_.normalAt = 3;
        } else if (allRows(rows, 3, Triple::Color)) {
          layout_.colorAt = 3;
        } else {
          fail();
        }
        break;
      case 7:
        layout_.colorAt = 4;
        break;
      case 9:
        if (allRows(rows, 3, Triple::Normal) && allRows(rows, 6, Triple::Color)) {
          layout_.normalAt = 3;
          layout_.colorAt = 6;
        } else if (allRows(rows, 3, Triple::Color) && allRows(rows, 6, Triple::Normal)) {
          layout_.colorAt = 3;
          layout_.normalAt = 6;
        } else {
          fail();
        }
        break;
      default:
        break;
    }
    if (layout_.colorAt >= 0) {
      // 0..1 colours: all values within [0,1] and at least one fraction.
      const auto at = static_cast<std::size_t>(layout_.colorAt);
      bool withinUnit = true;
      bool fractional = false;
      for (const Row& r : rows) {
        for (std::size_t k = at; k < at + 3; ++k) {
          withinUnit = withinUnit && r.values[k] <= 1.0;
          fractional = fractional || r.values[k] != std::floor(r.values[k]);
        }
      }
      layout_.unitColors = withinUnit && fractional;
    }
  }

  Splat splatOf(const double* values) const {
    Splat s = detail::greySplat();
    for (std::size_t k = 0; k < 3; ++k) s.position[k] = static_cast<float>(values[k]);
    if (layout_.normalAt >= 0) {
      const auto at = static_cast<std::size_t>(layout_.normalAt);
      for (std::size_t k = 0; k < 3; ++k) s.normal[k] = static_cast<float>(values[at + k]);
    }
    if (layout_.colorAt >= 0) {
      const auto at = static_cast<std::size_t>(layout_.colorAt);
      for (std::size_t k = 0; k < 3; ++k) {
        const double c = values[at + k];
        s.color[k] = layout_.unitColors ? detail::colorFromUnit(c) : detail::colorFromByte(c);
      }
    }
    return s;
  }

  void addRow(const Row& r) {
    builder_.add(splatOf(r.values.data()), r.line, 0);
    if ((++rows_ & 4095) == 0) builder_.progress(reader_.offset(), reader_.size());
  }

  // After the sniffed lines: blocks of whole lines are read at once, cut into
  // pieces at line ends and parsed on every core (cutting lines one by one
  // on one thread held the others back); the checks and the hand-over stay
  // in line order, and the first bad line is reported as reading line by
  // line would.
  void readRestInBlocks() {
    // Streamed out of core, a block is text held beside the block of points
    // that --memory-mb counts for the reader: a small one then.
    const std::size_t blockBytes = streaming_ ? std::size_t{1} << 20 : std::size_t{8} << 20;
    constexpr std::size_t kPieceBytes = std::size_t{256} << 10;
    // Mapped, the blocks are not copied on this thread first (a pipe is read
    // through the buffer).
    const std::unique_ptr<detail::MappedLineBlocks> mapped =
        detail::MappedLineBlocks::open(file_, reader_.offset());
    const auto offset = [&] { return mapped ? mapped->offset() : reader_.offset(); };
    std::vector<LinePiece> pieces;
    for (;;) {
      const std::uint64_t linesBefore = reader_.lineNumber();
      const std::string_view block =
          mapped ? mapped->next(blockBytes, linesBefore) : reader_.readLineBlock(blockBytes);
      if (block.empty()) return;
      // Pieces end after a "\n" (the block's last may not).
      std::size_t count = 0;
      for (std::size_t at = 0; at < block.size(); ++count) {
        std::size_t stop = std::min(block.size(), at + kPieceBytes);
        if (stop < block.size()) {
          const std::size_t nl = block.find('\n', stop - 1);
          stop = nl == std::string_view::npos ? block.size() : nl + 1;
        }
        if (pieces.size() <= count) pieces.emplace_back();
        pieces[count].text = block.substr(at, stop - at);
        at = stop;
      }
      parallelFor(
          count, 0, [&](std::size_t p) { parsePiece(pieces[p]); }, 1);
      std::uint64_t line = linesBefore;
      if (handOverAtOnce(pieces, count)) {
        for (std::size_t p = 0; p < count; ++p) line += pieces[p].lines;
      } else {
        handOverInOrder(pieces, count, line);
      }
      reader_.countLines(line - linesBefore);
      // Sized from the file so far.
      const std::uint64_t done = offset();
      if (done > 0 && done < reader_.size()) {
        const double perByte = static_cast<double>(rows_) / static_cast<double>(done);
        const auto expected =
            static_cast<std::uint64_t>(perByte * static_cast<double>(reader_.size())) + 1024;
        builder_.expect(expected, reader_.size() / 6 + 16);
      }
      builder_.progress(done, reader_.size());
    }
  }

  static constexpr std::uint64_t kNoBadLine = ~std::uint64_t{0};

  struct LinePiece;

  // A block whose pieces all parsed and are finite, copied into the cloud on
  // all threads (each piece to its place); false, with nothing handed over,
  // for any other block, or where the points go to a sink.
  bool handOverAtOnce(std::vector<LinePiece>& pieces, std::size_t count) {
    std::size_t total = 0;
    for (std::size_t p = 0; p < count; ++p) {
      if (!pieces[p].allFinite || pieces[p].bad != kNoBadLine) return false;
      total += pieces[p].splats.size();
    }
    if (total == 0) return true;  // comments and blank lines only
    const std::span<Splat> room = builder_.appendRoom(total);
    if (room.empty()) return false;  // the points go to a sink
    std::vector<std::size_t> at(count + 1, 0);
    for (std::size_t p = 0; p < count; ++p) at[p + 1] = at[p] + pieces[p].splats.size();
    parallelFor(
        count, 0,
        [&](std::size_t p) {
          std::copy(pieces[p].splats.begin(), pieces[p].splats.end(),
                    room.begin() + static_cast<std::ptrdiff_t>(at[p]));
        },
        1);
    builder_.keepRoom(false);
    rows_ += total;
    return true;
  }

  // The pieces one after another, checked in line order: the first bad line
  // or non-finite point is named as reading line by line would. `line` moves
  // past the block.
  void handOverInOrder(std::vector<LinePiece>& pieces, std::size_t count, std::uint64_t& line) {
    for (std::size_t p = 0; p < count; ++p) {
      LinePiece& piece = pieces[p];
      const std::span<const Splat> parsed(piece.splats);
      if (piece.allFinite) {
        builder_.addPreparedFinite(parsed);
      } else {
        for (std::size_t j = 0; j < parsed.size(); ++j)
          builder_.addPrepared(parsed[j], line + 1 + piece.lineOf[j], 0);
      }
      rows_ += parsed.size();
      if (piece.bad != kNoBadLine) failAtLine(file_, line + 1 + piece.bad, piece.badMessage);
      line += piece.lines;
    }
  }

  // Whole lines of a block, and what parsing them on one thread found.
  struct LinePiece {
    std::string_view text;
    std::uint64_t lines = 0;
    std::vector<Splat> splats;
    std::vector<std::uint32_t> lineOf;  // each splat's line in the piece, from 0
    bool allFinite = true;
    std::uint64_t bad = kNoBadLine;  // the first line that does not parse
    std::string badMessage;
  };

  // Parses a piece's lines up to its first bad one.
  void parsePiece(LinePiece& piece) const {
    piece.lines = 0;
    piece.splats.clear();
    piece.lineOf.clear();
    piece.allFinite = true;
    piece.bad = kNoBadLine;
    std::vector<std::string_view> fields;
    std::vector<double> values(columns_);
    std::string_view rest = piece.text;
    const auto take = [&](std::uint64_t index) {
      Splat s = splatOf(values.data());
      detail::CloudBuilder::prepare(s);
      piece.allFinite = piece.allFinite && detail::isFinite(s);
      piece.splats.push_back(s);
      piece.lineOf.push_back(static_cast<std::uint32_t>(index));
    };
    while (!rest.empty()) {
      // A plain line in one pass over its bytes; any other the way below.
      if (const char* next = detail::parsePlainLine(rest.data(), rest.data() + rest.size(),
                                                    values.data(), columns_)) {
        take(piece.lines++);
        rest.remove_prefix(static_cast<std::size_t>(next - rest.data()));
        continue;
      }
      const std::size_t nl = rest.find('\n');
      std::string_view l = rest.substr(0, nl);
      rest = nl == std::string_view::npos ? std::string_view{} : rest.substr(nl + 1);
      const std::uint64_t index = piece.lines++;
      if (!l.empty() && l.back() == '\r') l.remove_suffix(1);
      const std::size_t hash = l.find('#');
      if (hash != std::string_view::npos) l = l.substr(0, hash);
      if (!detail::parseNumbers(l, values.data(), columns_)) {
        // Anything else (a blank line, a bad value, another count) the slow
        // way, which names what is wrong.
        detail::splitFields(l, fields);
        if (fields.empty()) continue;
        std::string message;
        if (fields.size() != columns_) {
          message = std::to_string(fields.size()) + " values, but line " +
                    std::to_string(firstLine_) + " has " + std::to_string(columns_) +
                    " (the layout is fixed by the first line)";
        } else {
          for (std::size_t i = 0; i < columns_ && message.empty(); ++i)
            if (!detail::parseDouble(fields[i], values[i]))
              message = "not a number: '" + std::string(fields[i]) + "'";
        }
        if (!message.empty()) {
          piece.bad = index;
          piece.badMessage = std::move(message);
          return;
        }
      }
      take(index);
    }
  }

  const std::filesystem::path& file_;
  detail::FileReader reader_;
  detail::CloudBuilder builder_;
  std::vector<std::string_view> fields_;
  std::size_t columns_ = 0;
  std::uint64_t firstLine_ = 0;
  std::uint64_t countLine_ = 0;
  std::uint64_t expectedCount_ = 0;
  std::uint64_t rows_ = 0;
  bool streaming_ = false;
  Layout layout_;
};

}  // namespace

PointCloud readXyz(const std::filesystem::path& file, const ReadOptions& options) {
  XyzParser parser(file, options);
  return parser.run();
}

}  // namespace pointillist::preprocess
